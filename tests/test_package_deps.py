"""Each package.xml declares what its code imports, so `rosdep install` can set a ROS 2 workspace
up; what rosdep has no key for is the one pip step of docs/ROS2_WORKSPACE.md, pinned as in
requirements.lock.
"""

from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = sorted(p for p in (ROOT / "src").iterdir() if (p / "package.xml").exists())

# Import name -> rosdep key (ros/rosdistro rosdep/python.yaml) or ROS package name.
ROSDEP_KEYS = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "yaml": "python3-yaml",
    "numba": "python3-numba",
    "matplotlib": "python3-matplotlib",
    "jinja2": "python3-jinja2",
    "tqdm": "python3-tqdm",
    "h5py": "python3-h5py",
    "rosbags": "python3-rosbags-pip",
    "websockets": "python3-websockets",
    **{
        ros: ros
        for ros in (
            "rclpy",
            "rcl_interfaces",
            "builtin_interfaces",
            "std_msgs",
            "rosgraph_msgs",
            "ament_index_python",
            "diagnostic_msgs",
            "std_srvs",
        )
    },
}
# Imported, but with no rosdep key: installed by docs/ROS2_WORKSPACE.md's pip step (PyPI
# distribution names).
PIP_ONLY = {
    "dask": "dask",
    "distributed": "distributed",
    "foxglove": "foxglove-sdk",
    "mcap": "mcap",
    "zstandard": "zstandard",
    "lz4": "lz4",
}


def imported_modules(package: Path) -> set[str]:
    """Top-level names of every module a package's code imports (at any depth of the file)."""
    names: set[str] = set()
    for path in package.rglob("*.py"):
        if path.name == "setup.py" or {"build", "test"} & set(path.relative_to(package).parts):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return {n for n in names if n not in sys.stdlib_module_names}


def declared(package: Path) -> set[str]:
    root = ET.parse(package / "package.xml").getroot()
    return {e.text.strip() for tag in ("depend", "exec_depend") for e in root.iter(tag) if e.text}


@pytest.mark.parametrize("package", PACKAGES, ids=[p.name for p in PACKAGES])
def test_package_xml_declares_every_import(package: Path) -> None:
    modules = imported_modules(package)
    unknown = modules - set(ROSDEP_KEYS) - set(PIP_ONLY) - {p.name for p in PACKAGES}
    assert not unknown, f"{package.name} imports {sorted(unknown)}: add them to this test's tables"
    needed = {ROSDEP_KEYS.get(m, m) for m in modules if m not in PIP_ONLY and m != package.name}
    missing = needed - declared(package)
    assert not missing, f"{package.name}/package.xml lacks <exec_depend> for {sorted(missing)}"


def test_the_pip_step_installs_what_rosdep_cannot_at_the_locked_versions() -> None:
    lock = dict(
        re.findall(r"^([A-Za-z0-9_.-]+)==(\S+)", (ROOT / "requirements.lock").read_text(), re.M)
    )
    lock = {name.lower(): version for name, version in lock.items()}
    guide = (ROOT / "docs" / "ROS2_WORKSPACE.md").read_text()
    step = re.search(r"^pip install (.+)$", guide, re.M)
    assert step, "docs/ROS2_WORKSPACE.md: no `pip install` line for what rosdep has no key for"
    used = set().union(*(imported_modules(p) for p in PACKAGES)) & set(PIP_ONLY)
    for module in sorted(used):
        distribution = PIP_ONLY[module]
        assert f"{distribution}=={lock[distribution]}" in step.group(1).split(), (
            f"docs/ROS2_WORKSPACE.md's pip step lacks {distribution}=={lock[distribution]}"
        )
