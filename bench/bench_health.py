"""Health monitor benchmark (issue 40): detection under the dSA loop, false alarms, CPU.

Run: scripts/in_env.sh python bench/bench_health.py [--quick]

Scenario: the simulated robot (nominal model, sensor noise on) under the dSA loop of
tests/test_control_dsa.py (sync 60 Hz, K_r ramped 1 -> 0 over 0.3-0.6 s, then self-excited at
about 159 Hz); the damage (wing inertia x0.8, stroke film x0.85, pitch film x0.85) lands between
blocks at DAMAGE_S. Latency = the event's wingbeat - the first wingbeat ending at or after
the damage. False alarms: 60 s of the unchanged robot. CPU: `health.step` on 10-sample blocks
(the loop's block) and on 200-sample messages (the loop's DDS batch to outside nodes), as a
share of one core at 20 kHz; baseline: the same core on the whole record in one call.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import REPO_ROOT, Figure, best_time_s, compare, print_table, write_json

sys.path.insert(0, str(REPO_ROOT / "tests"))
import health_sim as hs
from flaair_control.core import health as H
from flaair_control.health_io import health_params_from_config
from flaair_model.model import with_effect_on, with_effects
from flaair_model.model_io import load_model

DAMAGE_S = 3.0


def _events(params, vs, vp, dv):
    _, out = H.step(H.initial_state(params), H.HealthInputs(vs, vp, dv), params)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="20 s instead of 60 s unchanged")
    ap.add_argument("--json", type=Path, default=REPO_ROOT / "out" / "bench" / "health.json")
    args = ap.parse_args()
    model = load_model()
    params = health_params_from_config(model=model)
    figures: list[Figure] = []
    cases = [
        ("wing_inertia", 0.8, with_effects(model, {"wing_damage": {"inertia_factor": 0.8}})),
        (
            "stroke_film_gain",
            0.85,
            with_effect_on(model, "strain_transfer_loss", "stroke", {"efficiency": 0.85}),
        ),
        (
            "pitch_film_gain",
            0.85,
            with_effect_on(model, "strain_transfer_loss", "pitch", {"efficiency": 0.85}),
        ),
    ]
    for name, truth, damaged in cases:
        vs, vp, dv = hs.run(model, DAMAGE_S + 1.0, damaged, DAMAGE_S, seed=11)
        out = _events(params, vs, vp, dv)
        first = next(b.wingbeat for b in out.wingbeats if b.time_s >= DAMAGE_S)
        named = [e.parameter for e in out.events]
        ev = next((e for e in out.events if e.parameter == name), None)
        latency = ev.wingbeat - first if ev else float("nan")
        err = abs(ev.ratio - truth) if ev else float("nan")
        figures.append(
            compare(
                f"{name} x{truth}: detection latency",
                latency,
                "wingbeats",
                "<=",
                20,
                f"events: {named}",
            )
        )
        figures.append(
            compare(
                f"{name} x{truth}: |ratio - truth|",
                err,
                "",
                "<=",
                0.04,
                f"ratio {ev.ratio:.4f} +- {ev.stderr:.4f}" if ev else "no event",
            )
        )
        # every event but the one expected (a second event of the expected parameter counts too)
        figures.append(
            compare(
                f"{name} x{truth}: other parameters named",
                len(named) - bool(ev),
                "events",
                "==",
                0,
                f"events: {named}",
            )
        )
    duration = 20.0 if args.quick else 60.0
    vs, vp, dv = hs.run(model, duration, seed=12)
    out = _events(params, vs, vp, dv)
    figures.append(
        compare(
            f"unchanged robot, {duration:g} s under dSA: events",
            len(out.events),
            "events",
            "==",
            0,
            f"{len(out.wingbeats)} wingbeats",
        )
    )
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
