"""Health monitor benchmark (issue 53): 5 % changes, their causes, false alarms, CPU.

Run: scripts/in_env.sh python bench/bench_health.py [--quick]

Robots: the simulated robot (nominal model, sensor noise on) under each controller: the dSA loop
of tests/test_control_dsa.py (sync 60 Hz, K_r ramped 1 -> 0 over 0.3-0.6 s, then self-excited at
about 159 Hz) and a synchronous 40 V sine at 140 Hz. A change lands between blocks at DAMAGE_S:
a 5 % loss of the wing's inertia, either film's gain or the actuator's gain; two changes the
films and the drive cannot tell from another (the wing hinge's stiffness: the pitch film's
look-alike; the stroke's stiffness: the inertia's); and the stroke film's charge amplifier
drifting (its output's zero moving a tenth of the film's amplitude a second). Each change runs
on `SEEDS` noise seeds and every figure is the worst of them (a latency is a distribution: each
seed must meet the target; the per-seed values are printed beside it). Latency = the event's
wingbeat - the first wingbeat ending at or after the change. Cause right: on every seed, every
event (at least one) names the cause, or a cause whose look-alikes (`alternatives`) include it;
the step changes' single event is checked by "other parameters named".

False alarms: 10 minutes of the unchanged robot (84,000 wingbeats), split over both controllers
at two drive levels each (dSA gain 10 x its Hopf onset in the simulated loop's 0.5 ms blocks and
20 x in a target loop's 1 ms blocks; sine 25 V at 150 Hz and 45 V at 140 Hz), beside the rate
the thresholds were derived for (`change_test.false_alarms_per_hour` of each run's learned
test). A robot the model misses: films lagging 100 us, left uncompensated (their reading then
depends on the amplitude, which settles slowly after the configured K_r ramp: 90 Hz sync,
ramped 0.5-1.0 s), three 20 s runs, no event allowed. CPU: `health.step` on 10-sample blocks
(the loop's block) and on 200-sample messages
(the loop's DDS batch to outside nodes), as a share of one core at 20 kHz; baseline: the same
core on the whole record in one call.
"""

from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import REPO_ROOT, Figure, best_time_s, compare, info, print_table, write_json

sys.path.insert(0, str(REPO_ROOT / "tests"))
import health_sim as hs
from flaair_control.core import change_test
from flaair_control.core import health as H
from flaair_control.health_io import health_params_from_config
from flaair_model.model import Model, with_effect_on, with_effects
from flaair_model.model_io import load_model

DAMAGE_S = 2.0
CHANGE = 0.95  # every change: 5 % down
MAX_LATENCY = 20  # wingbeats from a change to its event (issue 53)
# Each change on this many noise seeds (the sensors' noise, and the dSA loop's drive that reads
# it): a latency is a distribution, and every seed must meet the target.
SEEDS = (11, 1, 2, 3, 4, 5, 6, 7)
DRIFT_PER_S = 0.1  # the stroke amplifier's drift: a tenth of the film's amplitude a second
CONTROLLERS = {"dSA": {}, "sine 40 V": {"sine": (40.0, 140.0), "block": 400}}
MISFIT_LAG_S = 1e-4  # the films' lag the model leaves out
MISFIT_RUNS = ((21, 20.0), (22, 20.0), (23, 20.0))  # (seed, seconds)
CONFIGURED_RAMP = {"kr": (1.0, 0.0, 0.5, 0.5), "sync_hz": 90.0}  # config/flaair.yaml's schedule
UNCHANGED = (  # (name, run options, seconds): 600 s in all
    ("dSA, 10 x onset, 0.5 ms blocks", {"mu_factor": 10.0}, 100.0),
    ("dSA, 20 x onset, 1 ms blocks", {"mu_factor": 20.0, "block": 20}, 150.0),
    ("sine 25 V 150 Hz", {"sine": (25.0, 150.0), "block": 400}, 175.0),
    ("sine 45 V 140 Hz", {"sine": (45.0, 140.0), "block": 400}, 175.0),
)


def changed(model: Model, cause: str) -> Model:
    """The robot with `cause` 5 % down."""
    pl = model.plant
    if cause == "wing_inertia":
        return with_effects(model, {"wing_damage": {"inertia_factor": CHANGE}})
    if cause in ("stroke_film_gain", "pitch_film_gain"):
        side = cause.split("_")[0]
        return with_effect_on(model, "strain_transfer_loss", side, {"efficiency": CHANGE})
    if cause == "actuator_gain":
        return replace(
            model, plant=replace(pl, actuator_gain_nm_per_v=pl.actuator_gain_nm_per_v * CHANGE)
        )
    if cause == "hinge_stiffness":  # k_h = I_p (2 pi f_p)^2
        f = pl.pitch_natural_frequency_hz * CHANGE**0.5
        return replace(model, plant=replace(pl, pitch_natural_frequency_hz=f))
    if cause == "stroke_stiffness":
        f = pl.stroke_natural_frequency_hz * CHANGE**0.5
        return replace(model, plant=replace(pl, stroke_natural_frequency_hz=f))
    raise ValueError(cause)


def _events(params, vs, vp, dv):
    state, out = H.step(H.initial_state(params), H.HealthInputs(vs, vp, dv), params)
    return state, out


def amplifier_drift(vs: np.ndarray, fs: float, start_s: float, per_s: float) -> np.ndarray:
    """The stroke film's voltages with its charge amplifier's output drifting from `start_s`
    at `per_s` of the film's amplitude (before the drift) a second.
    """
    n0 = int(start_s * fs)
    amplitude = (vs[:n0].max() - vs[:n0].min()) / 2.0
    out = vs.copy()
    out[n0:] += per_s * amplitude * np.arange(vs.size - n0) / fs
    return out


def change_case(args: tuple[str, str, int]) -> dict:
    """One changed robot under one controller and one noise seed: its events and the first
    wingbeat after the change.
    """
    cause, controller, seed = args
    model = load_model()
    params = health_params_from_config(model=model)
    opts = CONTROLLERS[controller]
    if cause == "stroke_amplifier_offset":  # the amplifier drifts; the robot is unchanged
        vs, vp, dv = hs.run(model, DAMAGE_S + 1.0, seed=seed, **opts)
        vs = amplifier_drift(vs, hs.FS, DAMAGE_S, DRIFT_PER_S)
    else:
        damaged = changed(model, cause)
        vs, vp, dv = hs.run(model, DAMAGE_S + 1.0, damaged, DAMAGE_S, seed=seed, **opts)
    _, out = _events(params, vs, vp, dv)
    first = next(b.wingbeat for b in out.wingbeats if b.time_s >= DAMAGE_S)
    return {"seed": seed, "first": first, "events": [e._asdict() for e in out.events]}


def unchanged_case(args: tuple[str, dict, float]) -> dict:
    """The unchanged robot for `seconds`: events, wingbeats and the derived false-alarm rate."""
    _, opts, seconds = args
    model = load_model()
    params = health_params_from_config(model=model)
    vs, vp, dv = hs.run(model, seconds, seed=12, **opts)
    state, out = _events(params, vs, vp, dv)
    f = [b.frequency_hz for b in out.wingbeats if b.valid]
    rate = change_test.false_alarms_per_hour(state.detector, sum(f) / max(len(f), 1))
    return {
        "events": [e._asdict() for e in out.events],
        "wingbeats": len(out.wingbeats),
        "rate": rate,
        "threshold": state.detector.threshold.tolist(),
    }


def misfit_case(args: tuple[int, float]) -> dict:
    """The unchanged robot whose films lag MISFIT_LAG_S (the model's do not), through the
    configured K_r ramp: its events, and its learned stroke-film baseline against the settled
    estimate (the last half of the run).
    """
    seed, seconds = args
    model = load_model()
    params = health_params_from_config(model=model)
    robot = with_effects(model, {"sensor_delay": {"delay_s": MISFIT_LAG_S}})
    state, out = _events(params, *hs.run(robot, seconds, seed=seed, **CONFIGURED_RAMP))
    settled = [b.estimate[1] for b in out.wingbeats if b.valid and b.time_s > seconds / 2]
    baseline = change_test.baseline_of(state.detector)
    return {
        "events": [e.parameter for e in out.events],
        "baseline": float("nan") if baseline is None else float(baseline.mean[1]),
        "settled": float(np.mean(settled)),
    }


def _latency(cause: str, r: dict) -> float:
    """Wingbeats from the change to the first event naming `cause` (inf: none)."""
    ev = next((e for e in r["events"] if e["parameter"] == cause), None)
    return float(ev["wingbeat"] - r["first"]) if ev else math.inf


def change_figures(cause: str, controller: str, runs: list[dict]) -> list[Figure]:
    """Latency, ratio and others named of a 5 % change of a part the monitor estimates, the
    worst over the noise seeds (each must meet the target).
    """
    latency = [_latency(cause, r) for r in runs]
    found = [next((e for e in r["events"] if e["parameter"] == cause), None) for r in runs]
    error = [abs(ev["ratio"] - CHANGE) if ev else math.inf for ev in found]
    others = [
        [e["parameter"] for e in r["events"] if e is not ev]
        for r, ev in zip(runs, found, strict=True)
    ]
    label = f"{cause} x{CHANGE}, {controller}, worst of {len(runs)} seeds"
    within = sum(lat <= MAX_LATENCY for lat in latency)
    return [
        compare(
            f"{label}: detection latency",
            max(latency),
            "wingbeats",
            "<=",
            MAX_LATENCY,
            f"{within}/{len(runs)} seeds within; per seed "
            + ", ".join(f"{lat:g}" for lat in latency),
        ),
        compare(
            f"{label}: |ratio - truth|",
            max(error),
            "",
            "<=",
            0.02,
            "ratios " + ", ".join(f"{ev['ratio']:.4f}" if ev else "none" for ev in found),
        ),
        # every event but the one expected (a second event of the expected parameter counts too)
        compare(
            f"{label}: other parameters named",
            sum(len(o) for o in others),
            "events",
            "==",
            0,
            f"named besides: {sorted({p for o in others for p in o}) or 'none'}",
        ),
    ]


def cause_figure(cause: str, controller: str, runs: list[dict]) -> Figure:
    """Whether, on every seed, every event names `cause` (itself or among the named cause's
    look-alikes), and there is one: a drift that goes on growing is reported again each time
    it has moved past the test's drift from the baseline learned after the last report.
    """
    right = [
        bool(r["events"])
        and all(e["parameter"] == cause or cause in e["alternatives"] for e in r["events"])
        for r in runs
    ]
    said = [
        H.change_text(e["parameter"], e["ratio"], e["stderr"], e["offset_deg"], e["alternatives"])
        + f", {e['wingbeat'] - runs[0]['first']} wingbeats after"
        for e in runs[0]["events"]
    ]
    what = (
        f"stroke amplifier drifting {DRIFT_PER_S:.0%} of its amplitude a second"
        if cause == "stroke_amplifier_offset"
        else f"{cause} x{CHANGE}"
    )
    return compare(
        f"{what}, {controller}: cause named on every seed",
        float(all(right)),
        "",
        "==",
        1.0,
        f"{sum(right)}/{len(runs)} seeds right; seed {runs[0]['seed']}: {said}",
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="(the same runs: the figures need them)")
    ap.add_argument("--json", type=Path, default=REPO_ROOT / "out" / "bench" / "health.json")
    args = ap.parse_args()
    model = load_model()
    params = health_params_from_config(model=model)
    figures: list[Figure] = []
    measured = ("wing_inertia", "stroke_film_gain", "pitch_film_gain", "actuator_gain")
    lookalikes = ("hinge_stiffness", "stroke_stiffness", "stroke_amplifier_offset")
    cases = [(c, k) for c in measured + lookalikes for k in CONTROLLERS]
    runs = [(c, k, seed) for c, k in cases for seed in SEEDS]
    with ProcessPoolExecutor(2) as pool:
        long_runs = pool.map(unchanged_case, UNCHANGED)
        misfit_runs = pool.map(misfit_case, MISFIT_RUNS)
        changes = list(pool.map(change_case, runs, chunksize=4))
        long_results, misfit = list(long_runs), list(misfit_runs)
    for cause, controller in cases:
        seeds = [r for run, r in zip(runs, changes, strict=True) if run[:2] == (cause, controller)]
        if cause in measured:
            figures.extend(change_figures(cause, controller, seeds))
        figures.append(cause_figure(cause, controller, seeds))
    events = sum(len(r["events"]) for r in long_results)
    wingbeats = sum(r["wingbeats"] for r in long_results)
    seconds = sum(s for *_, s in UNCHANGED)
    for (name, _, s), r in zip(UNCHANGED, long_results, strict=True):
        figures.append(
            info(
                f"unchanged {name}, {s:g} s: derived false alarms",
                r["rate"],
                "per hour",
                f"{len(r['events'])} events in {r['wingbeats']} wingbeats; CUSUM h "
                + ", ".join(f"{h:.1f}" for h in r["threshold"])
                + " sigmas",
            )
        )
    expected = sum(
        r["rate"] * s / 3600.0 for (_, _, s), r in zip(UNCHANGED, long_results, strict=True)
    )
    figures.append(
        compare(
            f"unchanged robot, {seconds / 60:g} min over both controllers: events",
            events,
            "events",
            "==",
            0,
            f"{wingbeats} wingbeats; the derived rates expect {expected:.2f} in this time",
        )
    )
    figures.append(
        compare(
            f"unchanged robot the model misses (films lag {MISFIT_LAG_S * 1e6:g} us), configured "
            f"K_r ramp, {len(MISFIT_RUNS)} x {MISFIT_RUNS[0][1]:g} s: events",
            sum(len(r["events"]) for r in misfit),
            "events",
            "==",
            0,
            "stroke film baseline / settled: "
            + ", ".join(f"{r['baseline'] / r['settled']:.4f}" for r in misfit),
        )
    )
    vs, vp, dv = hs.run(model, 10.0, seed=12)
    n = int(10.0 * hs.FS)
    s, p, d = vs[:n], vp[:n], dv[:n]
    whole = best_time_s(lambda: _events(params, s, p, d), repeats=2)
    for block in (10, 200):

        def live(block=block):
            st = H.initial_state(params)
            for i in range(0, n, block):
                st, _ = H.step(
                    st, H.HealthInputs(s[i : i + block], p[i : i + block], d[i : i + block]), params
                )

        wall = best_time_s(live, repeats=2)
        share = 100.0 * wall / 10.0
        figures.append(
            compare(
                f"monitor CPU at 20 kHz, {block}-sample blocks",
                share,
                "% of a core",
                "<",
                15,
                f"whole record {100 * whole / 10.0:.2f} %",
            )
        )
    print_table(figures)
    write_json(figures, args.json)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
