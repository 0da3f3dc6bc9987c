"""Discrepancy workflow on off-nominal robots: names, status, parameters, natural frequencies, time.

Run: python bench/bench_discrepancy.py [--json out.json]
[--draws 30] [--discover-draws 60] [--baseline-draws 5] [--jobs 2] [--sweep] [--subset]

Robots come from the project's randomized generator (`discrepancy.offnominal.random_robot`): every
fitted plant parameter off nominal (natural frequencies within +-3 %, damping, gain and couplings
within +-15 %), noise 1-2x the model's, truth at 20 kHz or at a 2 kHz video rate (NaN between
frames), the standard run set (chirp 20-200 Hz at 100 V and 50 V, stepped sine 60-200 Hz).
Families: off-nominal with no effect; with one vocabulary effect (each in turn, random strength;
wing_damage is reproduced exactly by a plant change, so the right answer names nothing); with a
pair of effects; with physics outside the vocabulary (a drifting pitch-sensor gain, a second
stroke resonance).

Every robot is scored by one rule (`flaair_analysis.exact_score`): right iff its status, its
named effects and its discovered terms (site and form) all equal the truth's, nothing missing
and nothing extra. Figures (each target printed is the one enforced; `info` has none):
- exactly right per family, the discovery family included: >= 90 %; baseline: the workflow
  without plant identification (identify: false in the discrepancy settings) on the first
  --baseline-draws robots of each vocabulary family;
- false discoveries on no-effect robots: effects <= 5 %, terms 0 %; terms the truth lacks on any
  robot: info;
- out-of-vocabulary robots flagged `unexplained`: >= 80 %;
- named effects with every fitted parameter within 10 % of the truth: >= 90 %;
- stroke and pitch natural frequencies within 0.5 % of the robot's (effective, for wing damage):
  100 % of the robots whose physics the vocabulary describes;
- time per robot data set: <= 60 s (max), each robot in one process while --jobs robots run at
  once (default 2: both cores of the machine busy); baseline: one simulation of the data set;
- discovery (family offnominal_discover, each of `DISCOVER_KINDS` in turn): exactly right
  >= 90 % (above); ending `explained` >= 80 %; time per robot <= 120 s; the right form among
  others, per-kind figures and coefficient errors: info, beside the exact score.
--sweep adds the fixed hidden-effect cases of `dataset_cases()` (confusion table in
out/bench/discrepancy_validation/validation.html).

--subset (`make bench`) analyses a subset drawn by a fixed seed (`SUBSET_SEED`) instead of every
draw: `SUBSET`'s robots, the no-identification baseline on the first `SUBSET_BASELINE` of each
family's, and with --sweep the hidden-effect cases of `SWEEP_SUBSET`. Every figure is still
printed, each count beside it and marked "subset" (`make bench-full` runs every draw and case).
Robots and hidden-effect cases share one process pool, the costliest kinds submitted first so
that none is left running alone at the end.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import replace
from functools import lru_cache
from pathlib import Path

from tqdm import tqdm

from benchlib import (
    REPO_ROOT,
    Figure,
    best_time_s,
    compare,
    info,
    one_numba_thread,
    print_table,
    write_json,
)
from flaair_analysis.discrepancy import analyse
from flaair_analysis.discrepancy.datasets import dataset_cases, make_run, make_runs
from flaair_analysis.discrepancy.offnominal import (
    COMPOSED_DISCOVER_KINDS,
    DISCOVER_KINDS,
    FAMILIES,
    OWN_FAMILY_EFFECTS,
    random_robot,
    true_plant,
)
from flaair_analysis.discrepancy.scoring import confusion_table, score_case, score_result
from flaair_common.strictjson import json_safe
from flaair_model.model_io import load_model
from flaair_model.settings import discrepancy as discrepancy_settings
from flaair_sim.core.plant import simulate
from flaair_tools.discrepancy.report import write_validation
from separating_run import separated_by_suggestion, separation_figures

TIME_TARGET_S = 60.0
ACCURACY_TARGET = 0.90
FALSE_DISCOVERY_TARGET = 0.05
OUTSIDE_TARGET = 0.80
PARAMETER_TOLERANCE = 0.10
FREQUENCY_TOLERANCE = 0.005
DISCOVER_TARGET = 0.90  # exactly right (status, names, terms)
DISCOVER_EXPLAINED_TARGET = 0.80
DISCOVER_TIME_S = 120.0
# The hysteretic actuators (offnominal_own): named, parameters within 10 %, explained.
OWN_TARGET = 0.80
FREQUENCIES = ("stroke_natural_frequency_hz", "pitch_natural_frequency_hz")

# The subset `make bench` runs: drawn by a fixed seed from every family's full draws (the same
# robots every run; docs/TESTING.md lists them and tests/test_bench_plan.py checks that it does).
# Nothing is chosen around a known miss: a miss the draw picks is counted as in the full run.
SUBSET_SEED = 47
FULL_DRAWS = {
    "offnominal_null": 30,
    "offnominal_single": 30,
    "offnominal_pair": 30,
    "offnominal_outside": 30,
    "offnominal_discover": 10 * len(DISCOVER_KINDS),
    "offnominal_own": 30,
}
SUBSET_SIZES = {
    "offnominal_null": 2,
    "offnominal_single": 9,
    "offnominal_pair": 2,
    "offnominal_outside": 2,
    "offnominal_discover": 6,
    "offnominal_own": 1,
}
SWEEP_SUBSET_SIZE = 5


def draw_subset(seed: int = SUBSET_SEED) -> dict[str, tuple[int, ...]]:
    """Each family's subset draws: `SUBSET_SIZES[f]` of its `FULL_DRAWS[f]`, by `seed`."""
    rng = random.Random(seed)
    return {
        family: tuple(sorted(rng.sample(range(FULL_DRAWS[family]), size)))
        for family, size in SUBSET_SIZES.items()
    }


def draw_sweep_subset(pool: tuple[str, ...], seed: int = SUBSET_SEED) -> tuple[str, ...]:
    """`SWEEP_SUBSET_SIZE` hidden-effect cases of `pool`, by `seed`, in the pool's order."""
    picked = set(random.Random(seed).sample(sorted(pool), SWEEP_SUBSET_SIZE))
    return tuple(name for name in pool if name in picked)


SUBSET: dict[str, tuple[int, ...]] = draw_subset()
# the no-identification baseline: the first robot of each family's subset (about 13 s each: a
# second would cost the subset 10 % more time)
SUBSET_BASELINE = 1
# The hidden-effect cases the sweep subset is drawn from: the 45 of the vocabulary's single and
# pair effects (an effect of a family of its own is benchmarked in that family).
SWEEP_POOL: tuple[str, ...] = tuple(
    c.name for c in dataset_cases() if not set(c.effect_names) & set(OWN_FAMILY_EFFECTS)
)
# Hidden-effect cases of `make bench`: `SWEEP_SUBSET_SIZE` of the pool, drawn by the same seed.
SWEEP_SUBSET: tuple[str, ...] = draw_sweep_subset(SWEEP_POOL)
# Submission order of the pool, costliest first (median seconds per robot in the full benchmark:
# discovery 20.9, pair 12.6, outside 7.7, one effect 5.4, no effect 2.5).
COST_ORDER = (
    "offnominal_discover",
    "offnominal_pair",
    "sweep",
    "offnominal_outside",
    "offnominal_single",
    "offnominal_own",
    "offnominal_null",
)


def judge(case, result, model) -> dict:
    """Per-robot outcome: exactly right or not (`score_result`: status, named effects and
    discovered terms all the truth's), parameter errors, natural-frequency errors.
    """
    expected = set(case.expected_names)
    found = {e.name for e in result.effects}
    score = score_result(case, result)
    exact = score.right
    errors = score_case(case, result).parameter_errors
    effect_ok = {}
    for name, _ in case.effects:
        if name in found:
            # every parameter, every chain
            mine = [v for k, v in errors.items() if k.startswith(f"{name}.")]
            effect_ok[name] = bool(mine) and all(v <= PARAMETER_TOLERANCE for v in mine)
    truth = true_plant(case, model)
    damage = dict(case.hidden).get("wing_damage", {}).get("inertia_factor", 1.0)
    freq_err = {
        k: result.plant_parameters[k]["value"] / (truth[k] / math.sqrt(damage)) - 1.0
        for k in FREQUENCIES
        if k in result.plant_parameters
    }
    return {
        "case": case.name,
        "family": case.name.rsplit("_", 1)[0],
        "expected": sorted(expected),
        "hidden_not_separable": [n for n, _ in case.hidden],
        "outside": case.outside,
        "found": sorted(found),
        "status": result.status,
        "expected_status": case.expected_status,
        "exact": exact,
        "problems": list(score.problems()),
        "parameter_errors": errors,
        "effect_parameters_ok": effect_ok,
        "frequency_errors": freq_err,
        "video_every": case.video_every,
        "noise_scale": case.noise_scale,
        "true_terms": [f"{t.kind}@{t.acts_on}" for t in case.terms],
        "discovered": [f"{d.term.kind}@{d.term.acts_on}" for d in result.discovered],
        "term_errors": _term_errors(case, result),
        # the composed forms' ranking: forms per step (most), wall time over every step
        "composed_ranked": max(
            (t.get("composed_ranked", 0) for t in result.discovery_tried), default=0
        ),
        "composed_rank_s": sum(t.get("composed_rank_s", 0.0) for t in result.discovery_tried),
    }


def _term_errors(case, result) -> dict:
    """Relative error of each true term's parameters where the same form was discovered."""
    found = {(d.term.kind, d.term.acts_on): d.term for d in result.discovered}
    out = {}
    for t in case.terms:
        f = found.get((t.kind, t.acts_on))
        if f is not None:
            out[f"{t.kind}.coefficient"] = abs(f.coefficient / t.coefficient - 1.0)
            for (k, v), (_, fv) in zip(t.shape, f.shape, strict=True):
                out[f"{t.kind}.{k}"] = abs(fv / v - 1.0)
    return out


def share(xs: list[bool]) -> float:
    return sum(xs) / len(xs) if xs else math.nan


@lru_cache(maxsize=1)
def _model():
    return load_model()


def analyse_robot(family: str, draw: int, baseline: bool) -> tuple[dict, dict | None]:
    """One robot of the generator, analysed (in a worker process): its outcome and, if asked, the
    outcome of the workflow without identification.
    """
    model = _model()
    case = random_robot(family, draw)
    runs = make_runs(case, model)
    t0 = time.perf_counter()
    result = analyse(runs, model, discrepancy_settings())
    elapsed = time.perf_counter() - t0
    outcome = judge(case, result, model) | {"elapsed_s": elapsed}
    if family == "offnominal_discover":
        outcome |= separated_by_suggestion(
            result,
            runs[0].fs_hz,
            lambda drive: make_run(case, model, "suggested_sine", drive, seed=case.seed + 7919),
            lambda extra: analyse((*runs, extra), model, discrepancy_settings()),
            lambda again: score_result(case, again).right,
        )
    base = None
    if baseline:
        old = analyse(runs, model, replace(discrepancy_settings(), identify=False))
        base = {"family": family, "exact": score_result(case, old).right}
    return outcome, base


@lru_cache(maxsize=1)
def _cases() -> dict:
    return {c.name: c for c in dataset_cases()}


def analyse_case(name: str):
    """One fixed hidden-effect case, analysed and scored (in a worker process)."""
    model = _model()
    case = _cases()[name]
    runs = make_runs(case, model)
    t0 = time.perf_counter()
    result = analyse(runs, model, discrepancy_settings())
    return score_case(case, result, time.perf_counter() - t0)


def select_jobs(
    families: list[str],
    draws: int,
    discover_draws: int,
    baseline_draws: int,
    subset: bool,
) -> list[tuple[str, int, bool]]:
    """(family, draw, with the no-identification baseline) of every robot to analyse.

    Parameters
    ----------
    families : families to draw, in `FAMILIES`.
    draws, discover_draws : robots per family and of the discovery family (every draw mode).
    baseline_draws : robots per family that also run the baseline (every draw mode).
    subset : `SUBSET`'s robots and the baseline on the first `SUBSET_BASELINE` of each family's,
        instead of the draw counts.
    """
    jobs = []
    for family in families:
        if subset:
            picked, n_base = SUBSET[family], SUBSET_BASELINE
        else:
            count = discover_draws if family == "offnominal_discover" else draws
            picked, n_base = tuple(range(count)), baseline_draws
        jobs += [
            (family, d, i < n_base and family != "offnominal_discover")
            for i, d in enumerate(picked)
        ]
    return jobs


def select_cases(subset: bool) -> tuple[str, ...]:
    """Names of the hidden-effect cases of --sweep: `SWEEP_SUBSET`, or every case."""
    return SWEEP_SUBSET if subset else tuple(c.name for c in dataset_cases())


def run_pool(
    jobs: list[tuple[str, int, bool]], cases: tuple[str, ...], workers: int
) -> tuple[list[dict], list[dict], list, float]:
    """Analyse the robots and the hidden-effect cases in one process pool, costliest kinds first.

    Returns (robot outcomes in `jobs`' order, baselines, case outcomes in `cases`' order,
    wall time in s).
    """
    tasks = [(COST_ORDER.index(job[0]), "robot", job) for job in jobs]
    tasks += [(COST_ORDER.index("sweep"), "case", name) for name in cases]
    tasks.sort(key=lambda t: t[0])  # stable: draws and cases stay in order within a kind
    outcomes, baseline, sweep = [], [], []
    start = time.perf_counter()
    pool = ProcessPoolExecutor(
        max_workers=max(1, workers), initializer=one_numba_thread if workers > 1 else None
    )
    try:
        futures = {
            pool.submit(analyse_robot, *arg)
            if kind == "robot"
            else pool.submit(analyse_case, arg): kind
            for _, kind, arg in tasks
        }
        for fut in tqdm(
            as_completed(futures), total=len(futures), desc="robots and cases", unit="robot"
        ):
            if futures[fut] == "case":
                sweep.append(fut.result())
                continue
            outcome, base = fut.result()
            outcomes.append(outcome)
            if base is not None:
                baseline.append(base)
    except KeyboardInterrupt:
        pool.shutdown(wait=False, cancel_futures=True)
        print("interrupted: no figures written", file=sys.stderr)
        raise SystemExit(130) from None
    pool.shutdown()
    wall = time.perf_counter() - start
    order = {(f, d): i for i, (f, d, _) in enumerate(jobs)}
    outcomes.sort(key=lambda o: order[(o["family"], int(o["case"].rsplit("_", 1)[1]))])
    sweep.sort(key=lambda o: cases.index(o.case))
    return outcomes, baseline, sweep, wall


def _count(k: int, n: int, subset: bool, noun: str = "") -> str:
    """The count beside a percentage: '(29/30 robots)' or '(6/6 robots, subset)'."""
    return f"({k}/{n}{' ' + noun if noun else ''}{', subset' if subset else ''})"


def _family_figures(
    outcomes: list[dict], baseline: list[dict], families: list[str], subset: bool
) -> list[Figure]:
    """Exactly right per family (status, named set and discovered set all the truth's), beside
    the workflow without identification; the discovery family is scored the same way.
    """
    figures = []
    for family in families:
        rows = [o for o in outcomes if o["family"] == family]
        if not rows:
            continue
        own = family == "offnominal_own"
        # a family of its own effect: right also means each parameter within 10 %
        exact = [o["exact"] and (not own or all(o["effect_parameters_ok"].values())) for o in rows]
        base = [b["exact"] for b in baseline if b["family"] == family]
        wrong = "; ".join(
            f"{o['case'][-3:]}: {', '.join(o['problems'])}" for o in rows if not o["exact"]
        )[:300]
        target = {"offnominal_discover": DISCOVER_TARGET, "offnominal_own": OWN_TARGET}.get(
            family, ACCURACY_TARGET
        )
        context = (
            f"without identification {100 * share(base):.0f} % ({sum(base)}/{len(base)})"
            if base
            else "no baseline run"
        )
        figures.append(
            compare(
                f"exactly right{', parameters within 10 %' if own else ''}, {family} "
                f"{_count(sum(exact), len(exact), subset, 'robots')}",
                100 * share(exact),
                "%",
                ">=",
                100 * target,
                context + (f"; wrong {wrong}" if wrong else ""),
            )
        )
    return figures


def _discovery_figures(outcomes: list[dict], subset: bool) -> list[Figure]:
    """The discovery family beside its exact score: the right form among others, ending
    explained, coefficient errors, time per robot.
    """
    discover = [o for o in outcomes if o["family"] == "offnominal_discover"]
    if not discover:
        return []
    among = [set(o["true_terms"]) <= set(o["discovered"]) for o in discover]
    kinds = sorted({o["true_terms"][0] for o in discover})
    explained = [o["status"] == "explained" for o in discover]
    errs = [v for o in discover for v in o["term_errors"].values()]
    d_times = [o["elapsed_s"] for o in discover]
    n = len(discover)
    per_kind_figures = []
    for k in kinds:  # per kind: exactly right, the form among others, explained, error, time
        rows = [o for o in discover if o["true_terms"][0] == k]
        k_errs = [e for o in rows for key, e in o["term_errors"].items() if "coefficient" in key]
        k_among = sum(set(o["true_terms"]) <= set(o["discovered"]) for o in rows)
        k_explained = sum(o["status"] == "explained" for o in rows)
        noun = "robots, composed" if "*" in k else "robots"
        per_kind_figures.append(
            info(
                f"discovery, kind {k} exactly right "
                + _count(sum(o["exact"] for o in rows), len(rows), subset, noun),
                100 * share([o["exact"] for o in rows]),
                "%",
                f"form among others {k_among}/{len(rows)}; explained {k_explained}/{len(rows)}; "
                "coefficient error median "
                + (f"{100 * statistics.median(k_errs):.1f} %" if k_errs else "n/a")
                + f"; time max {max(o['elapsed_s'] for o in rows):.0f} s",
            )
        )
    extra = "; ".join(
        f"{o['case'][-3:]}: {'+'.join(o['found'] + o['discovered']) or 'none'}"
        for o, a in zip(discover, among, strict=True)
        if a and not o["exact"]
    )[:200]
    separated, equivalent = separation_figures(
        discover,
        "discovery",
        lambda k, n_of, noun: _count(k, n_of, subset, noun),
        lambda o: o["case"][-3:],
    )
    ranking = [o for o in discover if o.get("composed_ranked")]
    rank_times = [o["composed_rank_s"] for o in ranking]
    ranked = info(
        f"discovery: composed forms ranked in a step (most, {len(ranking)} robots"
        f"{', subset' if subset else ''})",
        float(max((o["composed_ranked"] for o in ranking), default=0)),
        "forms",
        (
            f"ranking them, every step of a robot: median {statistics.median(rank_times):.1f} s, "
            f"max {max(rank_times):.1f} s"
        )
        if rank_times
        else "no discovery step ran",
    )
    return [
        separated,
        equivalent,
        ranked,
        info(
            f"discovery: right acts_on and form among others "
            f"{_count(sum(among), n, subset, f'robots, {len(kinds)} kinds')}",
            100 * share(among),
            "%",
            "secondary to exactly right; right form but not exact: " + (extra or "none"),
        ),
        compare(
            f"discovery: ending explained {_count(sum(explained), n, subset, 'robots')}",
            100 * share(explained),
            "%",
            ">=",
            100 * DISCOVER_EXPLAINED_TARGET,
            f"parameters of right forms within 10 %: {100 * share([e <= 0.1 for e in errs]):.0f}"
            f" % ({len(errs)})",
        ),
        compare(
            f"discovery: time per robot (max of {n}{', subset' if subset else ''})",
            max(d_times),
            "s",
            "<=",
            DISCOVER_TIME_S,
            f"median {statistics.median(d_times):.1f} s",
        ),
        *per_kind_figures,
    ]


def _null_outside_figures(outcomes: list[dict], subset: bool) -> list[Figure]:
    """False discoveries (no-effect robots; terms the truth lacks on any robot); out-of-vocabulary
    robots flagged.
    """
    figures = []
    null = [o for o in outcomes if o["family"] == "offnominal_null"]
    if null:
        terms = [bool(o["discovered"]) for o in null]
        figures.append(
            compare(
                f"false discoveries of terms on no-effect robots "
                f"{_count(sum(terms), len(null), subset)}",
                100 * share(terms),
                "%",
                "<=",
                0.0,
            )
        )
        named = [bool(o["found"]) for o in null]
        figures.append(
            compare(
                f"false discoveries on no-effect robots "
                f"{_count(sum(named), len(null), subset, 'robots')}",
                100 * share(named),
                "%",
                "<=",
                100 * FALSE_DISCOVERY_TARGET,
            )
        )
    extra_terms = [bool(set(o["discovered"]) - set(o["true_terms"])) for o in outcomes]
    if outcomes:
        figures.append(
            info(
                f"robots with a term the truth lacks, every family "
                f"{_count(sum(extra_terms), len(outcomes), subset, 'robots')}",
                100 * share(extra_terms),
                "%",
                ", ".join(
                    f"{o['case']}: {'+'.join(sorted(set(o['discovered']) - set(o['true_terms'])))}"
                    for o, x in zip(outcomes, extra_terms, strict=True)
                    if x
                )[:200]
                or "none",
            )
        )
    outside = [o for o in outcomes if o["family"] == "offnominal_outside"]
    if outside:
        flagged = [o["status"] == "unexplained" for o in outside]
        figures.append(
            compare(
                f"out-of-vocabulary robots flagged unexplained "
                f"{_count(sum(flagged), len(outside), subset, 'robots')}",
                100 * share(flagged),
                "%",
                ">=",
                100 * OUTSIDE_TARGET,
            )
        )
    return figures


def _accuracy_figures(outcomes: list[dict], subset: bool) -> list[Figure]:
    """Named effects' parameters within 10 %; natural frequencies within 0.5 %."""
    named = [ok for o in outcomes for ok in o["effect_parameters_ok"].values()]
    worst = max((v for o in outcomes for v in o["parameter_errors"].values()), default=math.nan)
    figures = [
        compare(
            f"named effects with parameters within 10 % "
            f"{_count(sum(named), len(named), subset, 'effects')}",
            100 * share(named),
            "%",
            ">=",
            100 * ACCURACY_TARGET,
            f"worst parameter {100 * worst:.1f} % off",
        )
    ]
    for key in FREQUENCIES:
        # robots the vocabulary can describe; an extra resonance (outside) pulls the fitted
        # frequency
        errs = [
            abs(o["frequency_errors"][key])
            for o in outcomes
            if key in o["frequency_errors"] and not o["outside"] and not o["true_terms"]
        ]
        out_errs = [
            abs(o["frequency_errors"][key])
            for o in outcomes
            if key in o["frequency_errors"] and o["outside"]
        ]
        if not errs:
            continue
        within = [e <= FREQUENCY_TOLERANCE for e in errs]
        figures.append(
            compare(
                f"{key} within 0.5 % "
                f"{_count(sum(within), len(errs), subset, 'in-vocabulary robots')}",
                100 * share(within),
                "% of robots",
                ">=",
                100.0,
                f"median {100 * statistics.median(errs):.3f} %, worst "
                f"{100 * max(errs):.3f} %"
                + (f"; outside robots worst {100 * max(out_errs):.1f} %" if out_errs else ""),
            )
        )
    return figures


def build_figures(
    outcomes: list[dict],
    baseline: list[dict],
    sweep: list,
    *,
    families: list[str],
    jobs: int,
    wall_s: float,
    t_sim_s: float,
    subset: bool,
) -> list[Figure]:
    """Every figure of the benchmark from the robots' and cases' outcomes.

    Parameters
    ----------
    outcomes, baseline : `analyse_robot`'s outcomes and baselines.
    sweep : the hidden-effect cases' `score_case` outcomes (empty without --sweep).
    families : the families drawn.
    jobs : robots analysed at once.
    wall_s : wall time of the pool; t_sim_s: one simulation of a robot's run set.
    subset : the outcomes are `SUBSET`'s (each count is marked so).
    """
    figures = _family_figures(outcomes, baseline, families, subset)
    figures += _discovery_figures(outcomes, subset)
    figures += _null_outside_figures(outcomes, subset)
    figures += _accuracy_figures(outcomes, subset)
    times = [o["elapsed_s"] for o in outcomes if o["family"] != "offnominal_discover"]
    if times:
        figures.append(
            compare(
                f"time per robot data set (max of {len(times)}, {jobs} at once, "
                f"existing families{', subset' if subset else ''})",
                max(times),
                "s",
                "<=",
                TIME_TARGET_S,
                f"median {statistics.median(times):.1f} s; robots and cases {wall_s / 60:.1f} "
                f"min wall; 1 simulation of the set {1e3 * t_sim_s:.0f} ms",
            )
        )
    if sweep:
        table = confusion_table(sweep)
        figures.append(
            compare(
                f"hidden-effect dataset cases right "
                f"{_count(table['correct'], table['total'], subset, 'cases')}",
                100 * table["correct"] / table["total"],
                "%",
                ">=",
                100.0,
                ", ".join(o.case for o in sweep if not o.correct) or "none wrong",
            )
        )
    return figures


def figure_stem(name: str) -> str:
    """A figure's name without its counts: what stays the same in both modes."""
    return name.split(" (", 1)[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write the figures as JSON here")
    parser.add_argument("--draws", type=int, default=30, help="robots per family (default 30)")
    parser.add_argument(
        "--baseline-draws",
        type=int,
        default=5,
        help="robots per family for the no-identification baseline",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=min(2, os.cpu_count() or 1),
        help="robots analysed at once, one process each (default: 2, both cores)",
    )
    parser.add_argument(
        "--families",
        nargs="*",
        choices=FAMILIES,
        default=list(FAMILIES),
        help="families to draw (default: all six)",
    )
    parser.add_argument(
        "--discover-draws",
        type=int,
        default=10 * len(DISCOVER_KINDS),
        help="robots of the discovery family (default: each of its kinds 10 times; "
        f"{len(DISCOVER_KINDS)} kinds, {len(COMPOSED_DISCOVER_KINDS)} of them composed forms)",
    )
    parser.add_argument(
        "--sweep", action="store_true", help="also run the fixed hidden-effect cases"
    )
    parser.add_argument(
        "--subset",
        action="store_true",
        help="the fixed subset of `make bench` (SUBSET, SWEEP_SUBSET) instead of every draw",
    )
    args = parser.parse_args()
    model = _model()
    first = make_runs(random_robot(FAMILIES[0], 0), model)
    simulate(first[0].drive_v[:10], first[0].fs_hz, model)  # numba cache load, not timed
    t_sim = best_time_s(lambda: [simulate(r.drive_v, r.fs_hz, model) for r in first], repeats=3)

    jobs = select_jobs(
        args.families, args.draws, args.discover_draws, args.baseline_draws, args.subset
    )
    cases = select_cases(args.subset) if args.sweep else ()
    outcomes, baseline, sweep, wall = run_pool(jobs, cases, args.jobs)
    out_dir = REPO_ROOT / "out" / "bench"
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "discrepancy_offnominal.json").write_text(
        json.dumps(json_safe(outcomes), indent=2, allow_nan=False)
    )
    if sweep:
        write_validation(
            out_dir / "discrepancy_validation",
            [o.as_dict() for o in sweep],
            confusion_table(sweep),
            sum(o.elapsed_s for o in sweep),
        )
    figures = build_figures(
        outcomes,
        baseline,
        sweep,
        families=args.families,
        jobs=args.jobs,
        wall_s=wall,
        t_sim_s=t_sim,
        subset=args.subset,
    )
    print_table(figures)
    if args.json:
        write_json(figures, args.json)


if __name__ == "__main__":
    main()
