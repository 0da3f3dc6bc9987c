"""The workspace works the ROS way too: `source install/setup.bash` alone gives a working shell."""
from __future__ import annotations

import os
import subprocess

from rosproc import REPO_ROOT


def test_source_install_setup_bash_gives_rclpy_and_flaair_packages() -> None:
    # A fresh login shell: nothing of the current environment but HOME and a plain PATH.
    env = {"HOME": os.environ.get("HOME", "/root"), "PATH": "/usr/local/bin:/usr/bin:/bin"}
    script = (
        "source install/setup.bash && python -c 'import rclpy, flaair_msgs.msg, "
        "flaair_sim.core.plant, flaair_model.pvdf, flaair_common.params;print(rclpy.__file__)'"
    )
    result = subprocess.run(["bash", "-c", script], cwd=REPO_ROOT, env=env, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert str(REPO_ROOT / ".venv") in result.stdout


def test_setup_is_idempotent_and_quick_when_nothing_changed() -> None:
    result = subprocess.run([str(REPO_ROOT / "scripts" / "setup_env.sh")], cwd=REPO_ROOT,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "installing" not in result.stdout and "building" not in result.stdout, result.stdout


def test_the_numba_warm_up_reaches_every_kernel_it_names() -> None:
    # best effort by design, so a renamed kernel would only print "skipped": that is a failure here
    import sys

    result = subprocess.run([sys.executable, str(REPO_ROOT / "scripts" / "warm_numba.py")],
                            cwd=REPO_ROOT, capture_output=True, text=True, timeout=280)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "skipped" not in result.stdout + result.stderr, result.stdout + result.stderr
