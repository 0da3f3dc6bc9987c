"""checked_files: the one way FLAAIR opens a file it was given.

A file from a person or a lab is read only when it is a regular file (not a directory, a FIFO
or /dev/zero) of at most the size its kind may have (`LIMIT_BYTES`); YAML is composed without
letting aliases expand past `MAX_YAML_NODES` nodes or nest past `MAX_YAML_DEPTH` levels, and an
integer of more than `MAX_INT_DIGITS` digits is refused by its key. Errors are one line and
quote at most `QUOTE_CHARS` characters of the file (`quote`).
"""

from __future__ import annotations

import math
import os
import re
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

__all__ = [
    "LIMIT_BYTES",
    "MAX_INT_DIGITS",
    "MAX_YAML_DEPTH",
    "MAX_YAML_NODES",
    "QUOTE_CHARS",
    "CheckedFileError",
    "bracket_depth",
    "check_file",
    "check_numbers",
    "load_yaml_text",
    "printable",
    "quote",
    "read_bytes",
    "read_text",
    "read_yaml",
]

MIB = 1 << 20
# the largest file of each kind FLAAIR reads (a 20 kHz run of an hour is ~1.6 GB of CSV)
LIMIT_BYTES: dict[str, int] = {
    "model": MIB,
    "config": MIB,
    "rig": MIB,
    "manifest": MIB,
    "calibration": MIB,
    "validation": 64 * MIB,
    "table": 4 * MIB,  # a lab's sweep table is a few hundred rows (~10 kB); 4 MiB is ~100k
    "launch": MIB,
    "track": 512 * MIB,
    "mat": 2048 * MIB,
    "csv": 4096 * MIB,
}
MAX_YAML_NODES = 100_000  # nodes of a document with every alias expanded
MAX_YAML_DEPTH = 64
MAX_INT_DIGITS = 30
QUOTE_CHARS = 40
_UNPRINTABLE = re.compile("[\x00-\x08\x0a-\x1f\x7f-\x9f\u2028\u2029]")


class CheckedFileError(ValueError):
    """A file that is not one FLAAIR reads: the message is one line naming the file."""


def quote(value: Any, limit: int = QUOTE_CHARS) -> str:
    """`value` as text on one line, cut to `limit` characters (an ellipsis marks the cut)."""
    text = _UNPRINTABLE.sub("?", value if isinstance(value, str) else repr(value))
    return text if len(text) <= limit else text[: limit - 3] + "..."


def printable(text: str) -> str:
    """`text` (a name from a file or a path) as valid UTF-8 without control characters: bytes
    that were not UTF-8 (surrogate escapes) become U+FFFD, a control character '?'.
    """
    clean = text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
    return _UNPRINTABLE.sub("?", clean)


def check_file(path: str | Path, kind: str, pipe: bool = False) -> Path:
    """`path` if it names a regular file within the size limit of `kind`, else CheckedFileError.

    `pipe`: a FIFO is accepted too (a reader that streams it, `<(unzip -p runs.zip run.csv)`).
    """
    path = Path(path)
    try:
        info = path.stat()
    except OSError as exc:
        raise CheckedFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    _check_stat(path, info, kind, pipe)
    return path


def _check_stat(path: Path, info: os.stat_result, kind: str, pipe: bool = False) -> None:
    if stat.S_ISDIR(info.st_mode):
        raise CheckedFileError(f"{path}: is a directory, not a {kind} file")
    if pipe and stat.S_ISFIFO(info.st_mode):
        return
    if not stat.S_ISREG(info.st_mode):
        raise CheckedFileError(f"{path}: not a regular file (a device, FIFO or socket)")
    limit = LIMIT_BYTES[kind]
    if info.st_size > limit:
        raise CheckedFileError(
            f"{path}: {info.st_size} bytes, more than a {kind} file may have ({limit})"
        )


def read_bytes(path: str | Path, kind: str) -> bytes:
    """The bytes of a checked file (`check_file`); never blocks on a FIFO, never reads past
    the limit of `kind` even when the file grows while it is read.
    """
    path = check_file(path, kind)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise CheckedFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    with os.fdopen(fd, "rb") as handle:
        _check_stat(path, os.fstat(fd), kind)  # the file opened is the one checked
        data = handle.read(LIMIT_BYTES[kind] + 1)
    if len(data) > LIMIT_BYTES[kind]:
        raise CheckedFileError(f"{path}: more than a {kind} file may have ({LIMIT_BYTES[kind]})")
    return data


def read_text(path: str | Path, kind: str) -> str:
    """The UTF-8 text of a checked file (a byte-order mark is dropped)."""
    data = read_bytes(path, kind)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise CheckedFileError(f"{path}: not a UTF-8 text file (at byte {exc.start})") from None


def _expanded_nodes(root: yaml.Node) -> tuple[int, int]:
    """Nodes and depth of a composed document with every alias expanded (iterative: a shared
    node is sized once); CheckedFileError past the bounds or for a recursive alias.
    """
    sizes: dict[int, tuple[int, int]] = {}
    open_nodes: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        children = list(_children(node))
        if done:
            open_nodes.discard(key)
            below = [sizes[id(child)] for child in children]
            size = 1 + sum(n for n, _ in below)
            depth = 1 + max((d for _, d in below), default=0)
            if size > MAX_YAML_NODES:
                raise CheckedFileError(f"aliases expand past {MAX_YAML_NODES} nodes")
            if depth > MAX_YAML_DEPTH:
                raise CheckedFileError(f"nested deeper than {MAX_YAML_DEPTH} levels")
            sizes[key] = (size, depth)
            continue
        if key in sizes:
            continue
        if key in open_nodes:
            raise CheckedFileError("a recursive alias (a node that contains itself)")
        open_nodes.add(key)
        stack.append((node, True))
        stack.extend((child, False) for child in children if id(child) not in sizes)
    return sizes[id(root)]


def _children(node: yaml.Node) -> Iterator[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        yield from node.value
    elif isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            yield key
            yield value


class _BoundedLoader(yaml.SafeLoader):  # type: ignore[misc]  # PyYAML ships no type stubs
    """SafeLoader that sizes a document, aliases expanded, before constructing anything, and
    refuses a key written twice in one mapping (YAML would keep the last, silently).
    """

    def compose_document(self) -> yaml.Node | None:
        node = super().compose_document()
        if node is not None:
            _expanded_nodes(node)
        return node

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[tuple[str, str]] = set()
        for key, _ in node.value:
            if isinstance(key, yaml.ScalarNode) and key.value != "<<":
                if (key.tag, key.value) in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"key {quote(key.value, 30)} written twice", key.start_mark
                    )
                seen.add((key.tag, key.value))
        mapping: dict[Any, Any] = super().construct_mapping(node, deep)
        return mapping


def check_numbers(data: Any, where: str, key: str = "") -> None:
    """Refuse an integer of more than `MAX_INT_DIGITS` digits anywhere in `data`, by its key,
    and a key or text holding a control character or a line break (one-line messages name them).
    """
    if isinstance(data, dict):
        for name, value in data.items():
            if isinstance(name, str) and _UNPRINTABLE.search(name):
                raise CheckedFileError(f"{where}: a key with a control character: {quote(name)}")
            check_numbers(value, where, f"{key}.{quote(name, 24)}" if key else quote(name, 24))
    elif isinstance(data, list):
        for index, value in enumerate(data):
            check_numbers(value, where, f"{key}[{index}]")
    elif isinstance(data, str) and _UNPRINTABLE.search(data):
        raise CheckedFileError(f"{where}: {key or 'value'}: a control character in {quote(data)}")
    elif isinstance(data, int) and abs(data) >= 10**MAX_INT_DIGITS:
        digits = int(math.log10(abs(data))) + 1
        raise CheckedFileError(
            f"{where}: {key or 'value'}: an integer of {digits} digits is out of range"
        )


def bracket_depth(text: str) -> int:
    """How deep `[` and `{` nest in `text`, counted without parsing (PyYAML and json take
    seconds and then a RecursionError on thousands of levels). Brackets inside strings count
    too: a bound of dozens of levels is never reached by a real file that way.
    """
    depth = deepest = 0
    for char in text:
        if char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth = max(0, depth - 1)
    return deepest


def load_yaml_text(text: str, where: str) -> Any:
    """The YAML document in `text`, bounded and checked; errors name `where` (file) and line."""
    if bracket_depth(text) > MAX_YAML_DEPTH:
        raise CheckedFileError(f"{where}: nested deeper than {MAX_YAML_DEPTH} levels")
    try:
        data = yaml.load(text, Loader=_BoundedLoader)  # a SafeLoader subclass
    except CheckedFileError as exc:
        raise CheckedFileError(f"{where}: {exc}") from None
    except ValueError as exc:  # an integer past Python's 4300 digits
        raise CheckedFileError(f"{where}: {quote(str(exc), 60)}") from None
    except RecursionError:
        raise CheckedFileError(f"{where}: nested deeper than {MAX_YAML_DEPTH} levels") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise CheckedFileError(f"{where}: {line}not valid YAML ({quote(problem, 80)})") from None
    check_numbers(data, where)
    return data


def read_yaml(path: str | Path, kind: str) -> Any:
    """The YAML document of a checked file of `kind` (`read_text`, `load_yaml_text`)."""
    return load_yaml_text(read_text(path, kind), str(path))
