"""A lab's ROS 2 workspace: a plain `colcon build` (no --symlink-install) of src/ into a directory
of its own, and a node started from that install tree, outside the source tree, finding its
configuration and the launch files through the ament index.

About 1.5 minutes (flaair_msgs through rosidl): marked `workspace`, run by `make bench`
(bench/bench_workspace.py), not by `make test`.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from flaair_common.graph import lease_domain

REPO_ROOT = Path(__file__).resolve().parents[1]
VENV = REPO_ROOT / ".venv"
PACKAGES = sorted(p.name for p in (REPO_ROOT / "src").iterdir() if (p / "package.xml").exists())

pytestmark = [pytest.mark.workspace, pytest.mark.timeout(900)]


def clean_env(**extra: str) -> dict[str, str]:
    """A shell environment with nothing of this checkout on it: only the venv as the ROS underlay
    (what a lab's /opt/ros/jazzy would be).
    """
    return {"HOME": os.environ.get("HOME", "/root"), "PATH": "/usr/bin:/bin", **extra}


def in_workspace(script: str, workspace: Path, **env: str) -> subprocess.Popen:
    return subprocess.Popen(
        ["bash", "-c", f"set -e; . '{VENV}/local_setup.sh'; {script}"],
        cwd=workspace,
        env=clean_env(**env),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("lab_ws")
    build = in_workspace(
        f"export CMAKE_PREFIX_PATH='{VENV}' COLCON_PREFIX_PATH='{VENV}' COLCON_HOME=$PWD/.colcon; "
        f"colcon --log-base log build --base-paths '{REPO_ROOT / 'src'}' --build-base build "
        f"--install-base install --cmake-args -DPython3_EXECUTABLE='{VENV}/bin/python' "
        "-DBUILD_TESTING=OFF",
        root,
    )
    out, _ = build.communicate(timeout=840)
    assert build.returncode == 0, out[-3000:]
    assert f"Summary: {len(PACKAGES)} packages finished" in out, out[-2000:]
    return root


def test_the_install_tree_holds_config_launch_files_and_every_node(workspace: Path) -> None:
    install = workspace / "install"
    config = install / "flaair_model" / "share" / "flaair_model" / "config"
    assert sorted(p.name for p in config.iterdir()) == sorted(
        p.name for p in (REPO_ROOT / "config").iterdir() if p.suffix in (".yaml", ".json")
    )
    assert not any(p.is_symlink() for p in config.iterdir())  # copied, not linked
    launch = install / "flaair_tools" / "share" / "flaair_tools" / "launch"
    assert sorted(p.name for p in launch.glob("*.launch.xml")) == sorted(
        p.name for p in (REPO_ROOT / "src" / "flaair_tools" / "launch").glob("*.launch.xml")
    )


def test_a_node_starts_from_the_install_tree_outside_the_source_tree(
    workspace: Path, tmp_path: Path
) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    lease = lease_domain()  # a domain of its own, though it exchanges nothing
    node = in_workspace(
        f". '{workspace}/install/setup.sh'; cd '{elsewhere}'; exec python "
        f"'{workspace}/install/flaair_sim/lib/flaair_sim/plant_node' --ros-args "
        "-r __node:=plant_ws",
        workspace,
        ROS_DOMAIN_ID=str(lease.domain_id),
        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
    )
    deadline, lines = time.monotonic() + 120, []
    try:
        while time.monotonic() < deadline:
            line = node.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "plant ready" in line:
                break
        assert any("[plant_ws]: plant ready: lockstep" in line for line in lines), "".join(lines)
    finally:
        os.killpg(node.pid, signal.SIGINT)
        rest, _ = node.communicate(timeout=60)
        lease.release()
    assert node.returncode == 0, "".join(lines) + rest
    # the module came from the install tree, and the launch files from its share
    where = in_workspace(
        f". '{workspace}/install/setup.sh'; cd '{elsewhere}'; python -c "
        "'import flaair_model, flaair_model.config as c; "
        "print(flaair_model.__file__); print(c.config_dir())'; "
        f"{workspace}/install/flaair_tools/lib/flaair_tools/flaair launch "
        "flaair_tools lockstep_loop.launch.xml --print",
        workspace,
    )
    out, _ = where.communicate(timeout=120)
    assert where.returncode == 0, out
    module, config, *commands = out.splitlines()
    assert module.startswith(str(workspace / "install")) and config == str(
        workspace / "install" / "flaair_model" / "share" / "flaair_model" / "config"
    )
    assert len(commands) == 3 and str(workspace / "install") in commands[0]
