"""Every DLTdv version's track export reads as the same points (docs/LAB_FILES.md, section 2):
DLTdv5-7 (``dlmwrite``, 6 significant digits), DLTdv8a before 8.4 (empty cells), DLTdv8a 8.4
(named points, ``_U``/``_V`` 2D columns), and the sparse export, each written as its writer
writes it (tests/lab_writers.py). A point is its position among the file's points, whichever
header names it; the rig gives that number or the name.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import lab_files as lf
import lab_writers as lw
from flaair_tools.bagio.dlt_tracks import read_xy_point, read_xyz_points
from flaair_tools.bagio.target_log import LabFileError

pytestmark = pytest.mark.timeout(60)
FRAMES = 240
ORDER = ["wing_leading_edge_2", "wing_leading_edge_1", "wing_trailing_edge_1"]  # file order


@pytest.fixture(scope="module")
def table() -> np.ndarray:
    """Frames x 9 (mm): LE2, LE1, TE1 of a flapping wing; every 13th frame untracked."""
    t = np.arange(FRAMES) / 2000.0
    points = lf.wing_points_mm(0.6 * np.sin(2 * np.pi * 120 * t), 0.5 * np.cos(2 * np.pi * 120 * t))
    table = np.column_stack([points[name] for name in ORDER])
    table[::13] = np.nan
    return table


def tip_table(cameras: int = 2) -> np.ndarray:
    """Frames x (2 x cameras) pixels of one point; camera c shifted by 100 c px."""
    t = np.arange(FRAMES) / 2000.0
    xy = np.column_stack([640 + 40 * np.sin(2 * np.pi * 120 * t), 360 + 0 * t])
    xy[::11] = np.nan
    return np.column_stack([xy + 100 * c for c in range(cameras)])


BY_NUMBER = {"wing_leading_edge_1": 2, "wing_trailing_edge_1": 3, "wing_leading_edge_2": 1}
NAMES = ["tipspar", "hinge", "trailing"]
BY_NAME = {"wing_leading_edge_1": "hinge", "wing_trailing_edge_1": 3, "wing_leading_edge_2": "pt1"}


@pytest.mark.parametrize(
    "writer, names, digits",
    [
        ("DLTdv7", ["pt1", "pt2", "pt3"], 6),
        ("DLTdv8a 8.3", ["pt1", "pt2", "pt3"], 6),
        ("DLTdv8a 8.4", NAMES, 15),
    ],
)
def test_every_writers_flat_3d_export_reads_as_the_same_points(
    tmp_path: Path, table, writer, names, digits
) -> None:
    path = lw.write_track(tmp_path / "run_xyzpts.csv", lw.xyz_header(names), table, writer)
    by_number = read_xyz_points(path, BY_NUMBER, 0.001)
    points = BY_NAME if writer == "DLTdv8a 8.4" else BY_NUMBER
    got = read_xyz_points(path, points, 0.001)
    for k, name in enumerate(ORDER):
        want = table[:, 3 * k : 3 * k + 3] * 0.001
        np.testing.assert_allclose(got[name], want, rtol=10.0 ** (1 - digits), atol=1e-12)
        np.testing.assert_array_equal(got[name], by_number[name])
        assert np.isnan(got[name][::13]).all()


@pytest.mark.parametrize(
    "writer, header",
    [
        ("DLTdv7", lw.xy_header(["pt1"], 2, "XY")),
        ("DLTdv8a 8.4", lw.xy_header(["pt1"], 2, "UV")),
        ("DLTdv8a 8.4", lw.xy_header(["tip"], 2, "UV")),
    ],
)
def test_every_writers_flat_2d_export_reads_as_the_same_point(tmp_path, writer, header) -> None:
    table = tip_table()
    path = lw.write_track(tmp_path / "run_xypts.csv", header, table, writer)
    for point in (1, "tip") if header[0].startswith("tip") else (1, "pt1"):
        got = read_xy_point(path, point, 2, "points.actuator_tip")
        np.testing.assert_allclose(got, table[:, 2:4], rtol=1e-5)


def test_the_sparse_export_reads_as_the_flat_file_it_stands_for(tmp_path: Path, table) -> None:
    flat = lw.write_track(tmp_path / "flat_xyzpts.csv", lw.xyz_header(["pt1", "pt2", "pt3"]), table)
    sparse = lw.write_sparse_track(tmp_path / "sparse_xyzpts.csv", table, 3)
    assert sparse.read_text().startswith("Sparse format 3D coordinates file\n240 9 ")
    got, want = read_xyz_points(sparse, BY_NUMBER, 0.001), read_xyz_points(flat, BY_NUMBER, 0.001)
    for name in ORDER:
        np.testing.assert_array_equal(got[name], want[name])
    tip = tip_table(cameras=1)
    sparse_2d = lw.write_sparse_track(tmp_path / "sparse_xypts.csv", tip, 2)
    np.testing.assert_allclose(read_xy_point(sparse_2d, 1, 1, "tip"), tip, rtol=1e-14)
    with pytest.raises(LabFileError, match=r"sparse_xypts\.csv: a 2D sparse track does not say"):
        read_xy_point(sparse_2d, 1, 2, "tip")


def test_a_sparse_file_whose_entries_disagree_with_its_counts_is_named(tmp_path, table) -> None:
    path = lw.write_sparse_track(tmp_path / "cut_xyzpts.csv", table, 3)
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:-5]) + "\n")
    with pytest.raises(LabFileError, match=r"cut_xyzpts.csv: \d+ sparse entries of 3 numbers; "):
        read_xyz_points(path, BY_NUMBER, 0.001)
    path.write_text("\n".join([lines[0], "240 9 1", "241 1 0.5"]) + "\n")
    with pytest.raises(LabFileError, match="outside the 240 x 9 track"):
        read_xyz_points(path, BY_NUMBER, 0.001)


def test_a_point_the_file_lacks_is_named_with_at_most_ten_of_the_files(tmp_path, table) -> None:
    names = [f"marker{k}" for k in range(12)]
    wide = np.tile(table[:, :3], (1, 12))
    path = lw.write_track(tmp_path / "run_xyzpts.csv", lw.xyz_header(names), wide)
    with pytest.raises(LabFileError) as refused:
        read_xyz_points(path, {"wing_leading_edge_1": "hinge"}, 0.001)
    message = str(refused.value)
    assert message.startswith(
        f"{path}: no point 'hinge' (wing_leading_edge_1); the file has points 1 'marker0', "
    )
    assert "10 'marker9', ... (12 in all)" in message and "marker10" not in message
    with pytest.raises(LabFileError, match=r"no point 13 \(wing_leading_edge_1\)"):
        read_xyz_points(path, {"wing_leading_edge_1": 13}, 0.001)
    with pytest.raises(LabFileError, match="the rig names one point twice"):
        read_xyz_points(path, {"a": 1, "b": "marker0"}, 0.001)


def test_a_2d_track_given_for_the_3d_points_is_named(tmp_path: Path) -> None:
    path = lw.write_track(tmp_path / "run_xypts.csv", lw.xy_header(["pt1"], 1), tip_table(1))
    with pytest.raises(LabFileError, match=r"column 1 'pt1_cam1_U' is not a DLTdv8 xyzpts column"):
        read_xyz_points(path, BY_NUMBER, 0.001)


@pytest.fixture(scope="module")
def sparse_bytes(table, tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("sparse") / "good_xyzpts.csv"
    return lw.write_sparse_track(path, table[:60], 3).read_bytes()


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    cut=st.floats(0.0, 0.999),
    flips=st.lists(st.tuples(st.floats(0.0, 0.999), st.integers(0, 255)), max_size=6),
)
def test_cut_or_damaged_sparse_tracks_give_a_lab_file_error_or_points(
    tmp_path_factory, sparse_bytes, cut, flips
) -> None:
    data = bytearray(sparse_bytes)
    for where, byte in flips:
        data[int(where * len(data))] = byte
    data = data[: max(1, int(len(data) * (1 - cut)))] if cut > 0.001 else data
    path = tmp_path_factory.mktemp("tracks") / "damaged_xyzpts.csv"
    path.write_bytes(bytes(data))
    try:
        got = read_xyz_points(path, BY_NUMBER, 0.001)
    except LabFileError as exc:
        assert "damaged_xyzpts.csv" in str(exc) and "\n" not in str(exc)
    else:
        assert all(v.ndim == 2 and np.isfinite(v).any() for v in got.values())


def test_a_sparse_file_announcing_more_rows_than_a_track_holds_is_refused(tmp_path) -> None:
    path = tmp_path / "huge_xyzpts.csv"
    path.write_text("Sparse format 3D coordinates file\n900000000000 9 1\n1 1 0.5\n")
    with pytest.raises(LabFileError, match="announces 900000000000 rows and 9 columns, more"):
        read_xyz_points(path, BY_NUMBER, 0.001)
