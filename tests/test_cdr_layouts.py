"""flaair_common.cdr derives its layouts from the .msg
files: they agree with rosidl's generated classes.
"""

from __future__ import annotations

import re

import pytest

from flaair_common import cdr, msgdefs
from flaair_common.msgdict import message_class

ROSIDL_KINDS = {
    "double": "float64",
    "uint64": "uint64",
    "uint8": "uint8",
    "octet": "uint8",
    "boolean": "bool",
    "string": "string",
    "sequence<double>": "float64[]",
    "sequence<boolean>": "bool[]",
}


@pytest.mark.parametrize("type_name", sorted(cdr.LAYOUTS))
def test_layout_fields_are_the_generated_message_fields_in_order(type_name: str) -> None:
    # rosidl, built from the same .msg
    generated = message_class(type_name).get_fields_and_field_types()
    names = list(generated)
    assert names[0] == "header" and generated["header"] == "std_msgs/Header"
    assert cdr.LAYOUTS[type_name].fields == tuple(
        (n, ROSIDL_KINDS[generated[n]]) for n in names[1:]
    )


def test_every_block_stream_has_a_layout_and_unsupported_definitions_are_named(monkeypatch) -> None:
    assert set(cdr.LAYOUTS) >= {
        "flaair_msgs/msg/SensorVoltageBlock",
        "flaair_msgs/msg/WingStateBlock",
        "flaair_msgs/msg/DriveCommandBlock",
        "flaair_msgs/msg/ControllerState",
    }
    assert cdr.DRIVE_COMMAND_BLOCK is cdr.LAYOUTS["flaair_msgs/msg/DriveCommandBlock"]
    with pytest.raises(ValueError, match="flaair_msgs/msg/Nope: not a flaair_msgs type"):
        cdr.layout_of("flaair_msgs/msg/Nope")
    with pytest.raises(AttributeError):
        cdr.NOT_A_LAYOUT  # noqa: B018
    from rosbags.typesys import get_types_from_msg

    fake = {
        **get_types_from_msg("float64 x", "flaair_msgs/msg/NoHeader"),
        **get_types_from_msg(
            "std_msgs/Header header\nfloat64[3] fixed", "flaair_msgs/msg/FixedArray"
        ),
        **get_types_from_msg(
            "std_msgs/Header header\nint16 y\nfloat64[] z", "flaair_msgs/msg/Plain"
        ),
    }
    monkeypatch.setattr(msgdefs, "project_types", lambda: fake)
    with pytest.raises(ValueError, match="NoHeader: the CDR codec needs a std_msgs/Header"):
        cdr.layout_of("flaair_msgs/msg/NoHeader")
    with pytest.raises(ValueError, match=re.escape("FixedArray.fixed: unsupported field type")):
        cdr.layout_of("flaair_msgs/msg/FixedArray")
    with pytest.raises(ValueError, match=re.escape("Plain.y: unsupported CDR kind 'int16'")):
        cdr.layout_of("flaair_msgs/msg/Plain")
