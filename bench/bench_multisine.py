"""Odd random-phase multisines: the analysis against the classic results, the class of every
channel of robots built to be linear, odd, even, odd+even or nonlinear in one sensor only, the
time of a whole `flaair multisine analyze`, and the contract's bad inputs.

Truth is never the code under test: the distortion levels of a static cubic and a static square
are the closed forms computed here by convolving the excited lines' indicator (the orderings
of each sum of lines counted); a robot's class per channel is how it was built (which term it
carries and which channels that term reaches).

  nice -n 10 python bench/bench_multisine.py
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from benchlib import REPO_ROOT, compare, info, print_table, write_json
from flaair_analysis.multisine.analysis import RunInput, analyse
from flaair_analysis.multisine.design import design_multisine, realization_drive
from flaair_common.runcsv import read_run, write_run
from flaair_model.model_io import model_from_dict
from flaair_sim.core.measured_run import synthesize_measured_run
from flaair_tools.cli import main as flaair

CHANNELS = ("stroke_sensor_v", "pitch_sensor_v", "stroke_deg", "pitch_deg")
CUBE = {"kind": "cube_angle", "acts_on": "stroke_dynamics", "parameters": {"coefficient": -2.5e-5}}
SQUARE = {"kind": "drive_square", "acts_on": "drive", "parameters": {"coefficient": 0.004}}
FILM = {
    "kind": "square_angle_sensor",
    "acts_on": "pitch_sensor_v",
    "parameters": {"coefficient": 0.2},
}
# robot -> (its discovered terms on a linear plant, the class of each channel as built)
ROBOTS = {
    "linear": ([], dict.fromkeys(CHANNELS, "linear")),
    "odd (stiffening stroke)": ([CUBE], dict.fromkeys(CHANNELS, "odd")),
    "even (drive squared)": ([SQUARE], dict.fromkeys(CHANNELS, "even")),
    "odd+even": ([CUBE, SQUARE], dict.fromkeys(CHANNELS, "odd+even")),
    "sensor only (pitch film squared)": (
        [FILM],
        {**dict.fromkeys(CHANNELS, "linear"), "pitch_sensor_v": "even"},
    ),
}


def default_design(realizations: int = 4):
    """The contract's default design at a fixed seed."""
    return design_multisine(
        band_hz=(100.0, 250.0), base_hz=2.0, lines_per_group=3, rms_v=25.0, periods=4,
        transient_periods=1, realizations=realizations, fs_hz=20000.0, max_v=100.0, seed=51,
    )  # fmt: skip


def closed_form_power(design, order: int, coefficient: float, lines: np.ndarray) -> np.ndarray:
    """E|Y(k)|^2 of coefficient * u^order (order 2 or 3) at `lines`, by convolution counts."""
    top = max(design.excited_lines)
    x = np.zeros(2 * top + 1)  # signed lines -top .. top
    for k in design.excited_lines:
        x[top + k] = x[top - k] = 1.0
    shift = order * top  # index of line 0 in an order-fold convolution

    def at(counts: np.ndarray, offset: int) -> np.ndarray:
        idx = lines + offset
        ok = (idx >= 0) & (idx < counts.size)
        return np.where(ok, counts[np.clip(idx, 0, counts.size - 1)], 0.0)

    def spread(factor: int) -> np.ndarray:  # indicator of factor * q for signed lines q
        out = np.zeros(factor * (2 * top) + 1)
        out[factor * (np.flatnonzero(x))] = 1.0
        return out

    if order == 2:
        ordered = at(np.convolve(x, x), shift)
        equal = at(spread(2), 2 * top)
        weight = 2.0 * (ordered - equal) + equal
    else:
        ordered = at(np.convolve(np.convolve(x, x), x), shift)
        pair = at(np.convolve(spread(2), x), shift)  # k1 = k2, any k3
        same = at(spread(3), 3 * top)
        two = 3.0 * (pair - same)
        weight = 6.0 * (ordered - two - same) + 3.0 * two + same
    return 2.0 * coefficient**2 * (design.amplitude_v / 2.0) ** (2 * order) * weight


def static_figures() -> list:
    """Static cubic and square: the measured odd / even level against the closed form."""
    design = design_multisine(
        band_hz=(1.0, 401.0), base_hz=1.0, lines_per_group=3, rms_v=1.0, periods=2,
        transient_periods=1, realizations=4, fs_hz=4096.0, max_v=10.0, seed=7,
    )  # fmt: skip
    u = np.stack([realization_drive(design, m) for m in range(4)])
    sigma = 1e-5
    noise = 2.0 * sigma**2 / (design.period_samples * design.periods)
    rng = np.random.default_rng(0)
    e = np.array(design.excited_lines)
    band = np.arange(e[0], e[-1] + 1)
    odd_lines = band[(band % 2 == 1) & ~np.isin(band, e)]
    even_lines = band[band % 2 == 0]
    figures = []
    for order, name, lines, key in (
        (3, "cubic", odd_lines, "odd"),
        (2, "square", even_lines, "even"),
    ):
        c = 0.05
        y = u + c * u**order + sigma * rng.standard_normal(u.shape)
        runs = [
            RunInput(
                f"{name}_{m}",
                design.fs_hz,
                {"drive_v": u[m], "stroke_sensor_v": y[m], "pitch_sensor_v": y[m]},
            )
            for m in range(4)
        ]
        ch = analyse(runs).doc["channels"]["stroke_sensor_v"]
        closed = 10 * np.log10(np.mean(closed_form_power(design, order, c, lines)) + noise)
        other = "even" if key == "odd" else "odd"
        figures += [
            compare(
                f"static {name}: {key} level vs closed form",
                abs(ch["levels_db"][key] - closed),
                "dB",
                "<=",
                1.0,
                f"closed form {closed:.1f} dB, read {ch['levels_db'][key]:.1f} dB",
            ),
            compare(
                f"static {name}: {other} level vs noise",
                abs(ch["levels_db"][other] - 10 * np.log10(noise)),
                "dB",
                "<=",
                1.0,
                f"class {ch['class']}",
            ),
        ]
    lin = u * 0.7 + sigma * rng.standard_normal(u.shape)
    runs = [
        RunInput(
            f"lin_{m}",
            design.fs_hz,
            {"drive_v": u[m], "stroke_sensor_v": lin[m], "pitch_sensor_v": lin[m]},
        )
        for m in range(4)
    ]
    levels = analyse(runs).doc["channels"]["stroke_sensor_v"]["levels_db"]
    figures.append(
        compare(
            "linear: noise estimate vs injected noise",
            abs(levels["noise"] - 10 * np.log10(noise)),
            "dB",
            "<=",
            1.0,
        )
    )
    return figures


def robot_runs(terms: list, design, seed: int) -> list[dict[str, np.ndarray]]:
    """A linear plant (no aerodynamic drag, 10 % structural damping) with `terms`, simulated with
    sensor and tracking noise on every realization; video at 2 kHz.
    """
    base = yaml.safe_load((REPO_ROOT / "config" / "model.yaml").read_text())
    base["plant"].update(aero_damping_nm_s2=0.0, aero_coupling_nm_s2=0.0)
    base["effects"] = {"structural_damping": {"damping_ratio": 0.1}}
    model = model_from_dict({**base, "discovered": terms})
    return measured_realizations(model, design, np.random.default_rng(seed))


def measured_realizations(model, design, rng: np.random.Generator) -> list[dict[str, np.ndarray]]:
    """`model` driven by every realization, with sensor and tracking noise; video at 2 kHz."""
    out = []
    for m in range(design.realizations):
        cols = synthesize_measured_run(realization_drive(design, m), design.fs_hz, model, rng)
        off = np.arange(cols["time_s"].size) % 10 != 0
        for c in ("stroke_deg", "pitch_deg"):
            cols[c][off] = np.nan
        out.append(cols)
    return out


def written(runs: list[dict[str, np.ndarray]], folder: Path, stem: str) -> list[Path]:
    """The runs as measured-run CSV files `folder/{stem}_1.csv`, ..."""
    paths = [folder / f"{stem}_{m + 1}.csv" for m in range(len(runs))]
    for path, cols in zip(paths, runs, strict=True):
        write_run(path, cols)
    return paths


def robot_figures() -> list:
    design = default_design()
    right, total, wrong = 0, 0, []
    for seed, (name, (terms, truth)) in enumerate(ROBOTS.items()):
        runs = [
            RunInput(f"{name}_{m}", design.fs_hz, c)
            for m, c in enumerate(robot_runs(terms, design, seed))
        ]
        got = {c: e["class"] for c, e in analyse(runs, design).doc["channels"].items()}
        for channel, want in truth.items():
            total += 1
            if got.get(channel) == want:
                right += 1
            else:
                wrong.append(f"{name} {channel}: {got.get(channel)} (built {want})")
    return [
        compare(
            f"channel class right ({total} channels, {len(ROBOTS)} robots)",
            100.0 * right / total,
            "%",
            ">=",
            100.0,
            "; ".join(wrong),
        )
    ]


# robot -> (its hidden term on the nominal model, the findings `discrepancy` must make, the site
# the multisine's even lines must point to first); truth is how each robot was built
HINGE = {
    "kind": "square_angle",
    "acts_on": "pitch_dynamics",
    "parameters": {"coefficient": 6e-7},
}
IN_DISCREPANCY = {
    "nominal": (None, set(), None),
    "hinge film squared": (
        {**FILM, "parameters": {"coefficient": 0.05}},
        {"square_angle_sensor@pitch_sensor_v"},
        "pitch_sensor_v",
    ),
    "hinge squared": (HINGE, {"square_angle@pitch_dynamics"}, "pitch_dynamics"),
}


def discrepancy_figures(tmp: Path, robots: list[str]) -> list:
    """`flaair discrepancy` on a short multisine set of each of `robots` (M = 2, P = 2, f0 = 4 Hz):
    the findings exactly right (nothing missing, nothing extra) and the even lines pointing first
    to the site the robot was built with.
    """
    design = design_multisine(
        band_hz=(100.0, 250.0), base_hz=4.0, lines_per_group=3, rms_v=25.0, periods=2,
        transient_periods=1, realizations=2, fs_hz=20000.0, max_v=100.0, seed=5,
    )  # fmt: skip
    base = yaml.safe_load((REPO_ROOT / "config" / "model.yaml").read_text())
    found_right = pointed_right = 0
    wrong, start = [], time.perf_counter()
    for seed, (name, (term, want, site)) in enumerate(IN_DISCREPANCY.items()):
        if name not in robots:
            continue
        model = model_from_dict({**base, "discovered": [term] if term else []})
        rng = np.random.default_rng(100 + seed)
        folder = tmp / f"discrepancy_{seed}"
        folder.mkdir()
        paths = written(measured_realizations(model, design, rng), folder, "realization")
        code, err = cli(["discrepancy", *map(str, paths), "--out", str(folder / "out")])
        if code != 0:
            wrong.append(f"{name}: exit {code} {err.strip()[:80]}")
            continue
        doc = json.loads((folder / "out" / "discrepancy.json").read_text())
        got = {f"{t['kind']}@{t['acts_on']}" for t in yaml.safe_load(
            (folder / "out" / "model.yaml").read_text()).get("discovered") or []}  # fmt: skip
        got |= {e["name"] for e in doc.get("effects", [])}
        found_right += got == want
        if got != want:
            wrong.append(f"{name}: found {sorted(got) or 'nothing'} (built {sorted(want)})")
        even = [
            f for f in doc["joint"]["multisine"]["before"]["localisation"]["findings"]
            if f["distortion"] == "even"
        ]  # fmt: skip
        first = even[0]["sites"] if even else []
        ok = (site is None and not even) or (site is not None and bool(first) and first[0] == site)
        pointed_right += ok
        if not ok:
            wrong.append(f"{name}: even lines point to {first or 'nothing'} (built {site})")
    n = len(robots)
    return [
        compare(f"discrepancy on a multisine set: findings exactly right ({n} robots)",
                100.0 * found_right / n, "%", ">=", 100.0, "; ".join(wrong)),
        compare(f"discrepancy on a multisine set: even lines point to the built site ({n} robots)",
                100.0 * pointed_right / n, "%", ">=", 100.0),
        info("discrepancy on a multisine set: time per robot",
             (time.perf_counter() - start) / n, "s"),
    ]  # fmt: skip


def cli(args: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = flaair(args)
    return code, err.getvalue()


def timing_and_refusals(tmp: Path) -> list:
    design = default_design()
    model = model_from_dict(yaml.safe_load((REPO_ROOT / "config" / "model.yaml").read_text()))
    rng = np.random.default_rng(3)
    paths = written(measured_realizations(model, design, rng), tmp, "run")
    runs = [str(p) for p in paths]
    # a first call imports matplotlib and Jinja2 (a process's one-time cost, not the analysis's)
    cli(["multisine", "analyze", *runs, "--out", str(tmp / "warm")])
    start = time.perf_counter()
    code, err = cli(["multisine", "analyze", *runs, "--out", str(tmp / "timed")])
    took = time.perf_counter() - start
    runs_in = [RunInput(p.name, design.fs_hz, dict(read_run(p).columns)) for p in paths]
    start = time.perf_counter()
    analyse(runs_in)
    core = time.perf_counter() - start
    figures = [
        compare(
            "analyze M=4 x P=4 periods at 20 kHz (CSV to report)",
            took if code == 0 else float("nan"),
            "s",
            "<",
            10.0,
            err.strip()[:80],
        ),
        info("  of which the analysis itself (no files, no figures)", core, "s"),
    ]
    # the refusals on a short design (N = 5000, T = 1, P = 2, M = 2): files of 15 000 rows
    short = design_multisine(
        band_hz=(100.0, 250.0), base_hz=4.0, lines_per_group=3, rms_v=25.0, periods=2,
        transient_periods=1, realizations=2, fs_hz=20000.0, max_v=100.0, seed=52,
    )  # fmt: skip
    pair = [
        synthesize_measured_run(realization_drive(short, m), short.fs_hz, model, rng)
        for m in range(2)
    ]
    one = pair[0]
    small = [str(tmp / "small_1.csv"), str(tmp / "small_2.csv")]
    for path, cols in zip(small, pair, strict=True):
        write_run(Path(path), cols)
    t = one["time_s"]

    def variant(name: str, **cols: np.ndarray) -> str:
        write_run(tmp / name, {**one, **cols})
        return str(tmp / name)

    stuck = one["stroke_sensor_v"].copy()
    stuck[8000:8006] = stuck[5000:].max()
    (tmp / "bad.csv").write_text(
        "time_s,drive_v,stroke_sensor_v,pitch_sensor_v\n0,1,1,1\n5e-05,1,x,1\n"
    )
    (tmp / "model.yaml").write_text("plant: [")
    full = tmp / "full"
    full.mkdir()
    (full / "keep").write_text("x")
    cases = {
        "a chirp": (
            [variant("chirp.csv", drive_v=50 * np.sin(2 * np.pi * (20 * t + 40 * t * t)))],
            "chirp.csv: no periodic",
        ),
        "fewer than 2 periods": (
            [small[1], variant("short.csv", **{k: v[:12500] for k, v in one.items()})],
            "short.csv: holds fewer",
        ),
        "an even line": (
            [variant("even.csv", drive_v=one["drive_v"] + 5 * np.cos(2 * np.pi * 200 * t))],
            "even.csv: not an odd multisine",
        ),
        "another design": (
            [
                small[0],
                variant("other.csv", drive_v=one["drive_v"] + 5 * np.cos(2 * np.pi * 44 * t)),
            ],
            "other.csv: another design",
        ),
        "a repeated realization": ([small[0], small[0]], "repeats the realization"),
        "a saturated sensor": (
            [variant("sat.csv", stroke_sensor_v=stuck)],
            "sat.csv: stroke_sensor_v saturated",
        ),
        "a format violation": ([str(tmp / "bad.csv")], "bad.csv: line 3, column stroke_sensor_v"),
        "an unreadable model": ([*runs, "--model", str(tmp / "model.yaml")], "--model"),
    }
    refused = 0
    missed = []
    for what, (args, expect) in cases.items():
        out = tmp / f"never_{refused}_{len(missed)}"
        code, err = cli(["multisine", "analyze", *args, "--out", str(out)])
        if code == 2 and expect in err and len(err.strip().splitlines()) == 1 and not out.exists():
            refused += 1
        else:
            missed.append(what)
    code, err = cli(["multisine", "analyze", *runs, "--out", str(full)])
    if code == 2 and "not empty" in err and [p.name for p in full.iterdir()] == ["keep"]:
        refused += 1
    else:
        missed.append("a non-empty --out")
    n = len(cases) + 1
    figures.append(
        compare(
            f"bad inputs refused in one line, nothing written ({n} kinds)",
            refused,
            "kinds",
            "==",
            n,
            ", ".join(missed),
        )
    )
    return figures


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument(
        "--all-discrepancy-robots",
        action="store_true",
        help="run `discrepancy` on every robot of IN_DISCREPANCY (default: the hinge film's only)",
    )
    args = parser.parse_args()
    robots = list(IN_DISCREPANCY) if args.all_discrepancy_robots else ["hinge film squared"]
    start = time.perf_counter()
    figures = static_figures() + robot_figures()
    with tempfile.TemporaryDirectory() as tmp:
        figures += timing_and_refusals(Path(tmp))
        figures += discrepancy_figures(Path(tmp), robots)
    figures.append(info("bench_multisine wall time", time.perf_counter() - start, "s"))
    print_table(figures)
    if args.json:
        write_json(figures, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
