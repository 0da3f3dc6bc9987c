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


_INTEGER_BITS = {
    "int8": (True, 8),
    "int16": (True, 16),
    "int32": (True, 32),
    "int64": (True, 64),
    "uint8": (False, 8),
    "uint16": (False, 16),
    "uint32": (False, 32),
    "uint64": (False, 64),
    "short": (True, 16),
    "long": (True, 32),
    "long long": (True, 64),
    "unsigned short": (False, 16),
    "unsigned long": (False, 32),
    "unsigned long long": (False, 64),
}


def _plain_problem(value: Any, slot_type: Any) -> str | None:
    """Why `value` cannot be a field of rosidl type `slot_type` (None: it can). rosidl's Python
    setters let a wrong type through (it fails later, in the serializer, with no field named).
    """
    kind = type(slot_type).__name__
    if kind == "BasicType":
        name = slot_type.typename
        if name == "boolean":
            return None if isinstance(value, bool) else f"a bool expected, got {value!r}"
        if name in _INTEGER_BITS:
            signed, bits = _INTEGER_BITS[name]
            low, high = (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if signed else (0, 2**bits - 1)
            if not isinstance(value, int) or isinstance(value, bool):
                return f"an integer ({name}) expected, got {value!r}"
            return None if low <= value <= high else f"{value} is outside {name} [{low}, {high}]"
        if name in ("float", "double", "long double"):
            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            return None if ok else f"a number ({name}) expected, got {value!r}"
        return None  # octet, char: as rosidl takes them
    if kind in ("UnboundedString", "BoundedString", "UnboundedWString", "BoundedWString"):
        if not isinstance(value, str):
            return f"a string expected, got {value!r}"
        limit = getattr(slot_type, "maximum_size", None)
        return None if limit is None or len(value) <= limit else f"longer than {limit}"
    if kind in ("UnboundedSequence", "BoundedSequence", "Array"):
        if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__"):
            return f"a list expected, got {value!r}"
        size = getattr(slot_type, "size", None)
        limit = getattr(slot_type, "maximum_size", None)
        if size is not None and len(value) != size:
            return f"{size} values expected, got {len(value)}"
        if limit is not None and len(value) > limit:
            return f"at most {limit} values expected, got {len(value)}"
        for k, item in enumerate(value):
            why = _plain_problem(
                item.item() if hasattr(item, "item") else item, slot_type.value_type
            )
            if why is not None:
                return f"item {k}: {why}"
    return None


def _nested_class(slot_type: Any) -> type | None:
    """The message class of a nested field (`slot_type` a rosidl_parser type), or of the
    elements of a sequence or array of messages; None for a field of plain values.
    """
    inner = getattr(slot_type, "value_type", slot_type)
    namespaces = getattr(inner, "namespaces", None)
    if namespaces is None:
        return None
    return message_class("/".join([*namespaces, inner.name]))


def from_dict(cls: type, values: dict[str, Any]) -> Any:
    """Build a message of class `cls` from nested dicts (a sequence of messages from a list of
    dicts); unknown keys and values of the wrong type are refused by name (ValueError).
    """
    if not isinstance(values, dict):
        raise ValueError(
            f"{cls.__name__} must be a mapping of field names to values, got {values!r}"
        )
    message = cls()
    fields = message.get_fields_and_field_types()
    slots = dict(zip(fields, getattr(cls, "SLOT_TYPES", ()), strict=False))
    for name, value in values.items():
        if name not in fields:
            raise ValueError(f"{cls.__name__} has no field '{name}' (fields: {', '.join(fields)})")
        current = getattr(message, name)
        nested = _nested_class(slots[name]) if name in slots else None
        try:
            if hasattr(current, "get_fields_and_field_types"):
                value = from_dict(type(current), value)
            elif nested is not None:
                if not isinstance(value, list):
                    raise ValueError(
                        f"a list of {nested.__name__} mappings expected, got {value!r}"
                    )
                value = [from_dict(nested, item) for item in value]
            else:
                why = _plain_problem(value, slots[name]) if name in slots else None
                if why is not None:
                    raise ValueError(why)
                if isinstance(current, array.array):
                    value = array.array(current.typecode, value)
            setattr(message, name, value)
        except (AssertionError, TypeError, ValueError, OverflowError) as exc:
            raise ValueError(f"{cls.__name__}.{name}: {exc}") from None
    return message
