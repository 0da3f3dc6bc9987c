"""The HTML report: self-contained, escaped, strict JSON beside it, collision timing in the text."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from rosproc import FLAAIR, isolated_env, run_offline

FS = 20000.0
EVIL = "<script>alert(1)</script>"


def measured(
    drive: np.ndarray, effects: dict | None = None, seed: int = 0
) -> dict[str, np.ndarray]:
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model
    from flaair_sim.core.measured_run import synthesize_measured_run

    return synthesize_measured_run(
        drive, FS, with_effects(load_model(), effects or {}), np.random.default_rng(seed)
    )


def sine(n: int) -> np.ndarray:
    return 75.0 * np.sin(2 * np.pi * 100.0 * np.arange(n) / FS)


def write_bag(
    out: Path,
    parts: list[tuple[str, dict[str, np.ndarray]]],
    experiment: dict | None = None,
    events: list[tuple[int, float]] = (),
) -> None:
    """Runs back to back in one bag (contiguous samples),
    an experiment description and monitor events.
    """
    from flaair_common.runcsv import MeasuredRun
    from flaair_tools import bagio
    from flaair_tools.bagio.import_runs import write_run

    store = bagio.typestore()
    with bagio.BagWriter(out, store=store) as writer:
        if experiment:
            writer.write_message(
                "/flaair/experiment",
                0,
                bagio.new_message(bagio.RUN_MARKER_TYPE, store, data=json.dumps(experiment)),
            )
        first = 0
        for name, columns in parts:
            write_run(
                writer,
                MeasuredRun(name, FS, columns),
                source_file=f"{name}.csv",
                start_ns=int(first / FS * 1e9),
                first_sample_index=first,
                block_size=10,
                frame_id="robot",
            )
            first += len(columns["time_s"])
        event_type = store.types["flaair_msgs/msg/CollisionEvent"]
        for kind, time_s in events:
            ns = round(time_s * 1e9)
            header = bagio.new_message(
                "std_msgs/msg/Header", store, stamp=bagio.time_msg(ns, store), frame_id="robot"
            )
            writer.write_message(
                "/flaair/collision/events",
                ns,
                event_type(
                    header=header,
                    kind=kind,
                    wingbeat_index=int(time_s * 100),
                    spectrum_rmse_deg=2.0,
                ),
            )


@pytest.fixture(scope="module")
def collision_report(tmp_path_factory) -> tuple[Path, dict]:
    from flaair_tools.analysis.analyze import analyze

    directory = tmp_path_factory.mktemp("col")
    obstacle = {"collision": {"stroke_limit_deg": 20.0}}
    parts = [
        ("no_collision", measured(sine(20000))),
        ("collision", measured(sine(20000), obstacle, 1)),
        ("cleared", measured(sine(20000), seed=2)),
    ]
    experiment = {
        "name": "collision",
        "kind": "collision",
        "description": "100 Hz drive, an obstacle for the middle second",
        "plant": {"obstacle_windows_s": [1.0, 2.0], "obstacle_stroke_limit_deg": 20.0},
        "runs": [
            {
                "name": "collision",
                "drive": {"waveform": "sine", "amplitude_v": 75.0, "frequency_hz": 100.0},
                "markers": [
                    ["no_collision", 0.0, 1.0],
                    ["collision", 1.0, 2.0],
                    ["cleared", 2.0, 3.0],
                ],
            }
        ],
    }
    write_bag(directory / "bag", parts, experiment, events=[(1, 1.0185), (2, 2.0412)])
    return directory / "rep", analyze([directory / "bag"], directory / "rep", progress=False)


def test_collision_timing_and_latency_are_in_the_text(collision_report: tuple[Path, dict]) -> None:
    out, report = collision_report
    obstacle = report["bags"][0]["collision"]["obstacle"]
    # the wing first reaches the 20 deg obstacle within the first wingbeat after it appears
    assert 1.0 <= obstacle["first_strike_s"] < 1.01
    assert obstacle["detection_latency_wingbeats"] == pytest.approx(
        (1.0185 - obstacle["first_strike_s"]) * 100.0
    )
    assert obstacle["clearance_latency_wingbeats"] == pytest.approx(4.12)
    html = (out / "report.html").read_text()
    text = re.sub(r"<[^>]+>", "", html)
    assert "onset at 1.018 s" in text and "clearance at 2.041 s" in text
    assert f"detection latency of {obstacle['detection_latency_wingbeats']:.2g} wingbeats" in text
    assert "collision seen" in text  # the verdict line
    assert report["bags"][0]["collision"]["runs"]["collision"]["collision"] is True


def test_report_is_self_contained_and_links_the_json(collision_report: tuple[Path, dict]) -> None:
    out, _report = collision_report
    html = (out / "report.html").read_text()
    sources = re.findall(r'src="([^"]*)"', html)
    assert sources and all(s.startswith("data:image/png;base64,") for s in sources)
    assert '<a href="report.json">' in html
    assert '"spectrum_rmse_deg"' not in html and len(html) < 2_000_000  # no JSON dump
    assert html.index("Summary") < html.index("<figure")  # the summary comes first
    # human labels, not keys
    assert "Collision metric with the obstacle (pitch FFT vs sine)" in html
    json.loads(
        (out / "report.json").read_text(),
        parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"),
    )


def test_run_names_are_escaped_everywhere(tmp_path: Path) -> None:
    from flaair_tools.analysis.analyze import analyze

    write_bag(tmp_path / "bag", [(EVIL, measured(sine(8000)))])
    analyze([tmp_path / "bag"], tmp_path / "rep", progress=False)
    html = (tmp_path / "rep" / "report.html").read_text()
    assert EVIL not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert all(
        name.endswith(".png") and "<" not in name
        for name in (p.name for p in (tmp_path / "rep").iterdir())
        if name != "report.html" and name != "report.json"
    )


def test_file_name_with_markup_is_escaped_through_the_cli(tmp_path: Path) -> None:
    from flaair_common.runcsv import write_run

    name = "<img src=x onerror=alert(1)>"
    write_run(tmp_path / f"{name}.csv", measured(sine(8000)))
    assert (
        run_offline(
            [FLAAIR, "import", str(tmp_path / f"{name}.csv"), "--out", str(tmp_path / "bag")],
            isolated_env(),
            120,
        ).returncode
        == 0
    )
    result = run_offline(
        [FLAAIR, "analyze", str(tmp_path / "bag"), "--out", str(tmp_path / "rep")],
        isolated_env(),
        120,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    html = (tmp_path / "rep" / "report.html").read_text()
    assert name not in html and "&lt;img src=x onerror=alert(1)&gt;" in html


def test_template_passes_nothing_through_raw() -> None:
    from flaair_tools.analysis import report

    template = (report.TEMPLATES / report.TEMPLATE).read_text()
    assert "|safe" not in template.replace(" ", "") and "autoescape false" not in template
    assert report.fmt(None) == "-" and report.fmt(25.391) == "25.4"
