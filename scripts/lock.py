"""Regenerate requirements.lock from a venv's `pip freeze` (used by `make lock`).

The ROS wheels also register a second distribution under the bare ROS package name
(e.g. `rclpy`, `action_msgs` beside `ros-rclpy`, `ros-action-msgs`); those are not on
PyPI under that name, so they are dropped from the lock.
"""

from __future__ import annotations

import subprocess
import sys


def main() -> None:
    venv_python = sys.argv[1]
    frozen = subprocess.run(
        [venv_python, "-m", "pip", "freeze"], check=True, capture_output=True, text=True
    ).stdout
    lines = [line for line in frozen.splitlines() if "==" in line]
    names = {line.split("==")[0].lower().replace("_", "-") for line in lines}
    kept = [
        line
        for line in lines
        if "ros-" + line.split("==")[0].lower().replace("_", "-") not in names
    ]
    print(
        "# Generated from requirements.in by 'make lock' (pip freeze of a fresh venv). Do not edit."
    )
    print("\n".join(sorted(kept, key=str.lower)))


if __name__ == "__main__":
    main()
