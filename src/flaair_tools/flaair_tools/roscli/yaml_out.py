"""Messages as `ros2 topic echo` prints them: YAML in the message's field order.

The same conversion as rosidl_runtime_py's `message_to_yaml` (which `ros2 topic echo` uses and
PyPI does not carry): bytes as characters, numpy numbers as Python numbers, arrays and strings
longer than `truncate_length` cut with a trailing '...', nested messages as mappings; dumped by
PyYAML with unicode allowed and no line wrapping. tests/test_ros2_conformance.py compares it with
the real command's output on the same topic.
"""

from __future__ import annotations

import array
import sys
from typing import Any

import numpy as np
import yaml

__all__ = ["DEFAULT_TRUNCATE_LENGTH", "field_of", "message_to_yaml", "to_plain"]

DEFAULT_TRUNCATE_LENGTH = 128  # ros2 topic echo's --truncate-length default


class _Ordered(dict):
    """A mapping YAML dumps in insertion order (the message's field order)."""


def _represent(dumper: yaml.Dumper, data: _Ordered) -> yaml.Node:
    items = [(dumper.represent_data(k), dumper.represent_data(v)) for k, v in data.items()]
    return yaml.nodes.MappingNode("tag:yaml.org,2002:map", items)


class _Dumper(yaml.Dumper):
    pass


_Dumper.add_representer(_Ordered, _represent)


def to_plain(value: Any, truncate_length: int | None = DEFAULT_TRUNCATE_LENGTH) -> Any:
    """`value` (a message, a field) as plain data, the way rosidl_runtime_py converts it."""
    if isinstance(value, bytes):
        text = "".join(chr(c) for c in value[:truncate_length])
        return (
            text + "..." if truncate_length is not None and len(value) > truncate_length else text
        )
    if isinstance(value, str):
        if truncate_length is not None and len(value) > truncate_length:
            return value[:truncate_length] + "..."
        return value
    if isinstance(value, (list, tuple, array.array, np.ndarray)):
        kind = tuple if isinstance(value, tuple) else list
        items = [to_plain(v, truncate_length) for v in value[:truncate_length]]
        if truncate_length is not None and len(value) > truncate_length:
            items.append("...")
        return kind(items)
    if isinstance(value, np.number):
        return value.item()
    if isinstance(value, (bool, float, int)):
        return value
    return _Ordered(
        (name, to_plain(getattr(value, name, None), truncate_length))
        for name in value.get_fields_and_field_types()
    )


def message_to_yaml(message: Any, truncate_length: int | None = DEFAULT_TRUNCATE_LENGTH) -> str:
    """YAML text of `message` (or of one field's value), as `ros2 topic echo` prints it."""
    return yaml.dump(
        to_plain(message, truncate_length),
        Dumper=_Dumper,
        allow_unicode=True,
        width=sys.maxsize,
        default_flow_style=False,
    )


def field_of(message: Any, path: str) -> Any:
    """The field `path` ('header.stamp') of `message`; ValueError naming it if there is none."""
    names = [name for name in path.split(".") if name]
    if not names:
        raise ValueError(f"Invalid field value '{path}'")
    value = message
    for name in names:
        if name not in getattr(value, "get_fields_and_field_types", dict)():
            raise ValueError(f"Invalid field '{path}': no field '{name}' in {type(value).__name__}")
        value = getattr(value, name)
    return value
