"""Shared pytest setup: the pure cores import straight from src/ (no build needed); every ROS
domain a test leased is released when the test ends."""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Iterator

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
for package_dir in sorted((REPO_ROOT / "src").iterdir()):
    if (package_dir / "setup.py").exists() and str(package_dir) not in sys.path:
        sys.path.insert(0, str(package_dir))

from rosproc import release_leases  # noqa: E402 - needs the path above


@pytest.fixture(autouse=True)
def _release_ros_domains() -> Iterator[None]:
    """A domain leased by `rosproc.isolated_env` is free again once its test ends."""
    yield
    release_leases()
