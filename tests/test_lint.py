"""ruff (ruff.toml) finds nothing in the project's
Python files; mypy (mypy.ini) nothing in the cores.

The ruff rules (ruff.toml): pyflakes (unused imports and names, undefined names), syntax errors,
and the import order (standard library, third party, FLAAIR). `ruff check --fix` repairs most.
mypy checks the pure cores (flaair_model and every package's core/) with their type hints.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RUFF = [sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise"]


@pytest.mark.timeout(120)
def test_ruff_finds_nothing() -> None:
    done = subprocess.run(
        [*RUFF, "src", "tests", "bench", "scripts"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=110,
    )
    assert done.returncode == 0, (
        f"ruff check (fix with: .venv/bin/ruff check --fix):\n{done.stdout}{done.stderr}"
    )


@pytest.mark.timeout(120)
def test_the_repository_rules_catch_an_unused_import_and_a_misplaced_one(tmp_path: Path) -> None:
    module = tmp_path / "module.py"
    module.write_text("import flaair_model\nimport os\n\nimport numpy\n\nprint(numpy.pi)\n")
    done = subprocess.run(
        [*RUFF, "--config", str(ROOT / "ruff.toml"), str(module)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=110,
    )
    assert done.returncode == 1
    assert (
        "F401" in done.stdout
        and "`os` imported but unused" in done.stdout
        and "I001" in done.stdout
    )


@pytest.mark.timeout(300)
def test_mypy_finds_nothing_in_the_cores() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "mypy", "--no-pretty", "--config-file", "mypy.ini"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=290,
    )
    assert done.returncode == 0, f"mypy (mypy.ini: the cores):\n{done.stdout}{done.stderr}"


@pytest.mark.timeout(300)
def test_mypy_catches_a_wrong_type_in_a_core(tmp_path: Path) -> None:
    module = tmp_path / "core_module.py"
    module.write_text(
        "def gain_v(drive_v: float) -> float:\n    return drive_v\n\n\ngain_v('60 V')\n"
    )
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "mypy",
            "--no-pretty",
            "--config-file",
            str(ROOT / "mypy.ini"),
            str(module),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=290,
    )
    assert done.returncode == 1 and 'incompatible type "str"; expected "float"' in done.stdout, (
        done.stdout
    )
