"""Stroke and pitch from tracked points (flaair_tools.bagio.video_angles): a wing placed in 3D from
known angles, under any `up` and `rest_span`, reads back the same angles; the actuator-tip path
follows the transmission ratio; points that define no direction are refused by name.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from flaair_tools.bagio import video_angles as va

finite = st.floats(-1.0, 1.0, allow_nan=False)
vectors = st.tuples(finite, finite, finite).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.2)
angles = st.floats(-3.0, 3.0, allow_nan=False)


def rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: `v` turned by `angle` about the unit `axis` (right hand)."""
    return (
        v * math.cos(angle)
        + np.cross(axis, v) * math.sin(angle)
        + axis * np.dot(axis, v) * (1 - math.cos(angle))
    )


def wing(
    up: np.ndarray,
    rest_span: np.ndarray,
    stroke: float,
    pitch: float,
    origin: np.ndarray,
    span_len: float,
    chord_len: float,
    rise: float,
    slide: float,
) -> tuple[np.ndarray, ...]:
    """LE1, TE1, LE2 (1 x 3 each) of a wing at `stroke` about `up` and `pitch` about its span."""
    u = up / np.linalg.norm(up)
    r = rest_span - np.dot(rest_span, u) * u
    r /= np.linalg.norm(r)
    s = rotate(r, u, stroke)
    c = rotate(-u, s, pitch)
    le1 = origin
    le2 = origin + span_len * s + rise * u  # LE2 may sit above the stroke plane
    te1 = origin + chord_len * c + slide * s  # TE1 may sit along the span
    return le1[None], te1[None], le2[None]


@settings(max_examples=300, deadline=None)
@given(
    up=vectors,
    rest=vectors,
    stroke=angles,
    pitch=angles,
    origin=vectors,
    span_len=st.floats(0.5, 20.0),
    chord_len=st.floats(0.2, 10.0),
    rise=finite,
    slide=finite,
)
def test_a_wing_placed_from_known_angles_reads_them_back(
    up, rest, stroke, pitch, origin, span_len, chord_len, rise, slide
) -> None:
    u = up / np.linalg.norm(up)
    # rest_span (nearly) along up: no zero stroke
    if np.linalg.norm(rest - np.dot(rest, u) * u) < 0.1:
        return
    le1, te1, le2 = wing(up, rest, stroke, pitch, origin, span_len, chord_len, rise, slide)
    assert va.stroke_from_span_rad(le1, le2, up, rest)[0] == pytest.approx(stroke, abs=1e-9)
    assert va.pitch_rad(le1, te1, le2, up)[0] == pytest.approx(pitch, abs=1e-9)


def test_signs_follow_the_right_hand_rule() -> None:
    up, rest = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    le1, te1, le2 = wing(
        up, rest, math.radians(30), math.radians(20), np.zeros(3), 10.0, 3.0, 0.0, 0.0
    )
    assert le2[0, 1] > 0  # +30 deg about +z turns +x towards +y
    assert math.degrees(va.stroke_from_span_rad(le1, le2, up, rest)[0]) == pytest.approx(30.0)
    assert math.degrees(va.pitch_rad(le1, te1, le2, up)[0]) == pytest.approx(20.0)


def test_untracked_frames_give_nan_and_leave_the_others_alone() -> None:
    up, rest = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    rows = [
        wing(up, rest, math.radians(a), 0.0, np.zeros(3), 10.0, 3.0, 0.0, 0.0) for a in (-10, 0, 10)
    ]
    le1, _te1, le2 = (np.vstack([r[i] for r in rows]) for i in range(3))
    le2[1] = np.nan
    stroke = np.degrees(va.stroke_from_span_rad(le1, le2, up, rest))
    assert np.isnan(stroke[1]) and stroke[[0, 2]] == pytest.approx([-10.0, 10.0])


@settings(max_examples=100, deadline=None)
@given(
    axis=st.tuples(finite, finite).map(np.array).filter(lambda v: np.linalg.norm(v) > 0.2),
    m_per_px=st.floats(1e-6, 1e-3),
    ratio=st.floats(100.0, 1e4),
    amplitude=st.floats(0.05, 1.0),
)
def test_the_actuator_tip_path_follows_the_transmission_ratio(
    axis, m_per_px, ratio, amplitude
) -> None:
    # zero mean: rest = mean tip
    stroke = amplitude * np.sin(np.linspace(0, 4 * np.pi, 400, endpoint=False))
    unit = axis / np.linalg.norm(axis)
    tip = np.array([512.0, 300.0]) + np.outer(stroke / ratio / m_per_px, unit)
    got = va.stroke_from_tip_rad(tip, axis, m_per_px, ratio)
    np.testing.assert_allclose(got, stroke, atol=1e-9 * ratio + 1e-9)


def test_tip_motion_across_the_axis_does_not_count() -> None:
    unit = np.array([1.0, 0.0])
    # moves only across the axis
    tip = np.column_stack([np.zeros(100), np.linspace(-50, 50, 100)])
    assert np.abs(va.stroke_from_tip_rad(tip, unit, 2e-5, 3000.0)).max() == 0.0


@pytest.mark.parametrize(
    "points, message",
    [
        ("le2=le1", "span (LE1, LE2): the points coincide in frame 1"),
        ("te1=le1", "chord (LE1, TE1): the points coincide in frame 1"),
    ],
)
def test_coinciding_points_are_refused_naming_the_frame(points, message) -> None:
    # the first row is frame 1, as DLTdv numbers frames
    up, rest = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    le1, te1, le2 = (
        np.vstack([a, a]) for a in wing(up, rest, 0.3, 0.2, np.zeros(3), 10.0, 3.0, 0.0, 0.0)
    )
    if points == "le2=le1":
        le2[0] = le1[0]
    else:
        te1[0] = le1[0]
    with pytest.raises(
        va.VideoGeometryError, match=message.replace("(", r"\(").replace(")", r"\)")
    ):
        va.pitch_rad(le1, te1, le2, up)


@pytest.mark.parametrize(
    "call, message",
    [
        (
            lambda: va.stroke_from_span_rad(
                np.zeros((1, 3)), np.ones((1, 3)), [0, 0, 0], [1, 0, 0]
            ),
            "geometry.up",
        ),
        (
            lambda: va.stroke_from_span_rad(
                np.zeros((1, 3)), np.ones((1, 3)), [0, 0, 1], [0, 0, 2]
            ),
            "rest_span is parallel to geometry.up",
        ),
        (
            lambda: va.stroke_from_tip_rad(np.full((3, 2), np.nan), [1, 0], 2e-5, 3000.0),
            "never tracked",
        ),
        (lambda: va.stroke_from_tip_rad(np.zeros((3, 2)), [1, 0], 0.0, 3000.0), "m_per_px"),
    ],
)
def test_rig_geometry_that_defines_no_angle_is_refused(call, message) -> None:
    with pytest.raises(va.VideoGeometryError, match=message):
        call()
