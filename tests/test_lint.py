"""ruff (ruff.toml) finds nothing in the project's Python files and `ruff format` would change
none; mypy --strict (mypy.ini) finds nothing in the pure code.

The ruff rules (ruff.toml): pyflakes (unused imports and names, undefined names), syntax errors,
the import order (standard library, third party, FLAAIR), docstrings, likely bugs (bugbear),
modern syntax, simpler forms, ruff's own rules and McCabe complexity 15. `ruff check --fix`
repairs most. mypy checks the pure code (flaair_model, every package's core/, flaair_analysis and
flaair_common's pure modules) with every --strict flag.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RUFF = [sys.executable, "-m", "ruff", "check", "--no-cache", "--output-format", "concise"]
LINTED = ["src", "tests", "bench", "scripts"]


@pytest.mark.timeout(120)
def test_ruff_finds_nothing() -> None:
    done = subprocess.run(
        [*RUFF, *LINTED],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=110,
    )
    assert done.returncode == 0, (
        f"ruff check (fix with: .venv/bin/ruff check --fix):\n{done.stdout}{done.stderr}"
    )


@pytest.mark.timeout(120)
def test_ruff_format_changes_nothing() -> None:
    """Formatting is ruff's, not a script's: `ruff format` would leave every file as it is."""
    done = subprocess.run(
        [sys.executable, "-m", "ruff", "format", "--check", "--no-cache", *LINTED],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=110,
    )
    assert done.returncode == 0, f"ruff format (fix with: .venv/bin/ruff format):\n{done.stdout}"


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


@pytest.mark.slow  # mypy over every core module
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
