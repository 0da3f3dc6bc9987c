"""The workspace works the ROS way too: `source install/setup.bash` alone gives a working shell."""

from __future__ import annotations

import os
import subprocess

import pytest

from rosproc import REPO_ROOT


@pytest.mark.slow  # sources the install in a new shell and imports rclpy
def test_source_install_setup_bash_gives_rclpy_and_flaair_packages() -> None:
    # A fresh login shell: nothing of the current environment but HOME and a plain PATH.
    env = {"HOME": os.environ.get("HOME", "/root"), "PATH": "/usr/local/bin:/usr/bin:/bin"}
    script = (
        "source install/setup.bash && python -c 'import rclpy, flaair_msgs.msg, "
        "flaair_sim.core.plant, flaair_model.pvdf, flaair_common.params;print(rclpy.__file__)'"
    )
    result = subprocess.run(
        ["bash", "-c", script], cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert str(REPO_ROOT / ".venv") in result.stdout


def test_setup_is_idempotent_and_quick_when_nothing_changed() -> None:
    result = subprocess.run(
        [str(REPO_ROOT / "scripts" / "setup_env.sh")],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert "installing" not in result.stdout and "building" not in result.stdout, result.stdout


@pytest.mark.slow  # compiles every numba kernel the warm-up names
def test_the_numba_warm_up_reaches_every_kernel_it_names() -> None:
    # best effort by design, so a renamed kernel would only print "skipped": that is a failure here
    import sys

    result = subprocess.run(
        [sys.executable, str(REPO_ROOT / "scripts" / "warm_numba.py")],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=280,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "skipped" not in result.stdout + result.stderr, result.stdout + result.stderr


def test_flaair_model_installs_every_config_file_to_its_share(monkeypatch) -> None:
    """A plain (not symlinked) `colcon build` copies config/ to share/flaair_model/config, where
    flaair_model.config.config_dir finds it through the ament index outside the source tree.
    """
    import runpy

    import setuptools

    captured: dict = {}
    monkeypatch.setattr(setuptools, "setup", lambda **kwargs: captured.update(kwargs))
    monkeypatch.chdir(REPO_ROOT / "src" / "flaair_model")
    runpy.run_path("setup.py")
    installed = dict(captured["data_files"])["share/flaair_model/config"]
    assert sorted(os.path.basename(p) for p in installed) == sorted(
        p.name for p in (REPO_ROOT / "config").iterdir() if p.suffix in (".yaml", ".json")
    )
    assert all(os.path.isfile(p) for p in installed)
