"""Convert any rosidl Python message to and from plain
dicts (rosidl_runtime_py is not installable here).
"""

from __future__ import annotations

import array
import importlib
from typing import Any


def message_class(type_name: str) -> type:
    """Import a message class from 'pkg/msg/Name' (or 'pkg/Name')."""
    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"message type '{type_name}' is not of the form pkg/msg/Name")
    try:
        module = importlib.import_module(f"{parts[0]}.{parts[1]}")
        return getattr(module, parts[2])
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"unknown message type '{type_name}'") from exc


def to_dict(message: Any) -> Any:
    """A message as nested dicts, lists and numbers (JSON-ready)."""
    if hasattr(message, "get_fields_and_field_types"):
        return {
            name: to_dict(getattr(message, name)) for name in message.get_fields_and_field_types()
        }
    if isinstance(message, (bytes, bytearray)):  # a rosidl `byte` (one) or raw bytes: numbers
        return message[0] if len(message) == 1 else list(message)
    if isinstance(message, (array.array, list, tuple)):
        return [to_dict(item) for item in message]
    if hasattr(message, "tolist"):
        return message.tolist()
    return message


def from_dict(cls: type, values: dict[str, Any]) -> Any:
    """Build a message of class `cls` from nested dicts; unknown keys are refused by name."""
    message = cls()
    fields = message.get_fields_and_field_types()
    for name, value in values.items():
        if name not in fields:
            raise ValueError(f"{cls.__name__} has no field '{name}' (fields: {', '.join(fields)})")
        current = getattr(message, name)
        if hasattr(current, "get_fields_and_field_types"):
            value = from_dict(type(current), value)
        elif isinstance(current, array.array):
            value = array.array(current.typecode, value)
        setattr(message, name, value)
    return message
