"""Where FLAAIR's configuration lives, and reading its ROS parameter files.

`config/` in the repository is the single source of truth for every tunable number.
Installed packages find it through FLAAIR_CONFIG_DIR (set by bin/flaair and
scripts/in_env.sh), then through the source tree (symlink install), then through
share/flaair_model/config (a plain `colcon build` on a stock ROS install).
"""

from __future__ import annotations

import copy
import os
from pathlib import Path
from typing import Any

from flaair_model.checked_files import CheckedFileError, read_yaml


class ConfigError(ValueError):
    """A configuration file is missing or malformed; the message names the file and key."""


CONFIG_DIR_ENV = "FLAAIR_CONFIG_DIR"


def config_dir() -> Path:
    """Return the directory holding FLAAIR's YAML configuration (the one locator)."""
    env = os.environ.get(CONFIG_DIR_ENV)
    if env:
        return Path(env)
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / "config" / "model.yaml").exists():
            return parent / "config"
    try:
        # deferred: ament_index_python comes with ROS; flaair_model (under the science) must
        # load without it, and its absence is the error below
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("flaair_model")) / "config"
    except Exception as exc:
        raise ConfigError("cannot find FLAAIR's config directory; set FLAAIR_CONFIG_DIR") from exc


def load_yaml(path: Path, kind: str = "config") -> Any:
    """Load a YAML file through `checked_files.read_yaml`, naming the file in any error."""
    try:
        return read_yaml(path, kind)
    except CheckedFileError as exc:
        raise ConfigError(str(exc)) from None


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for key, sub in value.items():
            _flatten(f"{prefix}.{key}" if prefix else str(key), sub, out)
    else:
        out[prefix] = value


def node_parameters(file_name: str, node_name: str, renamed: str | None = None) -> dict[str, Any]:
    """Return the flattened `ros__parameters` of `node_name` in config/`file_name`.

    The `/**` section (shared by every node) is read first, the node's own section over it, then
    a section named `renamed` (the name a node was given at launch, `-r __node:=plant2`), if any.
    Nested mappings become dotted names, as ROS 2 parameter files do.
    """
    path = config_dir() / file_name
    document = _parameter_document(path) or {}
    if not isinstance(document, dict):
        raise ConfigError(f"{path}: expected a mapping of node names to ros__parameters")
    out: dict[str, Any] = {}
    found = False
    keys = ["/**", node_name, f"/{node_name}"]
    if renamed and renamed != node_name:
        keys += [renamed, f"/{renamed}"]
    for key in keys:
        section = document.get(key)
        if isinstance(section, dict) and "ros__parameters" in section:
            _flatten("", section["ros__parameters"], out)
            found = found or key != "/**"
    if not found:
        raise ConfigError(f"{path}: no '{node_name}: ros__parameters:' section")
    return copy.deepcopy(out)  # the parsed document is cached: callers get their own values


_PARSED: dict[str, tuple[tuple[int, int], Any]] = {}


def _parameter_document(path: Path) -> Any:
    """`load_yaml(path)`, parsed again only when the file changes (mtime, size): a tool asks
    `node_parameters` for many sections of one file (parsing flaair.yaml takes ~50 ms).
    """
    try:
        status = path.stat()
    except OSError:
        return load_yaml(path)  # the named error
    stamp = (status.st_mtime_ns, status.st_size)
    cached = _PARSED.get(str(path))
    if cached is None or cached[0] != stamp:
        cached = _PARSED[str(path)] = (stamp, load_yaml(path))
    return cached[1]


def shared_parameters(file_name: str) -> dict[str, Any]:
    """The `/**` section of config/`file_name` (values every node receives), flattened."""
    document = _parameter_document(config_dir() / file_name) or {}
    out: dict[str, Any] = {}
    section = document.get("/**") if isinstance(document, dict) else None
    if isinstance(section, dict):
        _flatten("", section.get("ros__parameters", {}), out)
    return copy.deepcopy(out)


def shared_parameter_names(file_name: str) -> set[str]:
    """Names in the `/**` section of config/`file_name` (values every node may receive)."""
    return set(shared_parameters(file_name))
