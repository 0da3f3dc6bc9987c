"""flaair_msgs' message definitions, read once from its `.msg` files.

The one place that finds the `.msg` files (the source tree, then every install prefix) and
parses them with rosbags' parser. bagio registers them in its typestore (and embeds them in
bags); `flaair_common.cdr` derives its CDR layouts from the same field definitions.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import Any

from rosbags.typesys import get_types_from_msg

from flaair_model.config import ConfigError, config_dir

MSG_PACKAGE = "flaair_msgs"


class MsgDefinitionError(ValueError):
    """The project's `.msg` files cannot be found or do not define what is asked."""


def msg_dirs() -> list[Path]:
    """Directories that may hold flaair_msgs' `.msg` files: the source tree, then the install."""
    dirs: list[Path] = []
    try:
        repo = str(config_dir().parent)
    except ConfigError:
        repo = ""
    for base in (os.environ.get("FLAAIR_ROOT"), repo):
        if base:
            dirs.append(Path(base) / "src" / MSG_PACKAGE / "msg")
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / "share" / MSG_PACKAGE / "msg")
    unique: list[Path] = []
    for directory in dirs:
        if directory.is_dir() and directory.resolve() not in [d.resolve() for d in unique]:
            unique.append(directory)
    return unique


def project_msg_texts(directory: Path | None = None) -> dict[str, str]:
    """`.msg` texts of flaair_msgs by full type name ('flaair_msgs/msg/Name')."""
    directories = [directory] if directory is not None else msg_dirs()
    for candidate in directories:
        texts = {
            f"{MSG_PACKAGE}/msg/{p.stem}": p.read_text(encoding="utf-8")
            for p in sorted(candidate.glob("*.msg"))
        }
        if texts:
            return texts
    raise MsgDefinitionError(
        f"no {MSG_PACKAGE} .msg files found (looked in: "
        f"{', '.join(map(str, directories)) or 'nowhere'})"
    )


@functools.cache
def project_types() -> dict[str, Any]:
    """Rosbags field definitions of every flaair_msgs type: name -> (constants, fields)."""
    types: dict[str, Any] = {}
    for name, text in project_msg_texts().items():
        types.update(get_types_from_msg(text, name))
    return types
