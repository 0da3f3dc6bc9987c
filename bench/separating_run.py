"""Ambiguity answered by an experiment: where a robot's runs leave a discovered term's form tied
with the next best, the run the report suggests, simulated on the same truth and added, and
whether the forms are then told apart.

Both discovery benchmarks measure it with the same rule (`separated_by_suggestion`) and print it
as the same two figures (`separation_figures`): the share of tied robots the suggested run
separates (target: more than half), and the ties the suggestion itself says no run tried can
separate (the two models differ by less than the noise on every run it simulated; `info`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from benchlib import Figure, compare, info
from flaair_analysis.discrepancy.discovery_uncertainty import suggested_drive

# The suggested run should separate the two forms in most tied robots (more than half).
SEPARATED_TARGET = 0.5
NO_TIE = "no robot of this run left two forms tied that a run can tell apart"


def separated_by_suggestion(
    result: Any,
    fs_hz: float,
    measure: Callable[[Any], Any],
    analyse_with: Callable[[Any], Any],
    exact: Callable[[Any], bool],
) -> dict[str, Any]:
    """The tie the analysis `result` left, and what the suggested run makes of it.

    Parameters
    ----------
    result : the workflow's result on the robot's runs.
    fs_hz : the runs' sample rate (Hz).
    measure : drive_v -> the run that drive gives on the robot's truth, with its noise.
    analyse_with : the extra run -> the workflow's result on the robot's runs and that run.
    exact : a result -> whether it is exactly right for the robot.

    Returns
    -------
    {ambiguous, equivalent} and, for a tie: tied (the winner's form), tied_with (the next best's),
    and where the suggestion separates them: suggested, separated (every discovered form then
    distinguishable), exact_after.
    """
    tied = [d for d in result.discovered if d.uncertainty.get("distinguishable") is False]
    if not tied:
        return {"ambiguous": False, "equivalent": False}
    first = tied[0]
    suggestion = first.uncertainty["suggested_experiment"]
    names = {
        "tied": f"{first.term.kind}@{first.term.acts_on}",
        "tied_with": (first.uncertainty.get("next_best") or {}).get("term", ""),
    }
    if not suggestion["separates"]:  # the same on every run tried: nothing to measure
        return {"ambiguous": False, "equivalent": True} | names
    drive = suggested_drive(
        suggestion["drive_amplitude_v"], suggestion["frequency_hz"], fs_hz, suggestion["duration_s"]
    )
    again = analyse_with(measure(drive))
    told_apart = bool(again.discovered) and all(
        d.uncertainty.get("distinguishable") is not False for d in again.discovered
    )
    return {
        "ambiguous": True,
        "equivalent": False,
        **names,
        "suggested": (
            f"{suggestion['drive_amplitude_v']:.0f} V at {suggestion['frequency_hz']:.0f} Hz"
        ),
        "separated": told_apart,
        "exact_after": bool(exact(again)),
    }


def separation_figures(
    outcomes: Sequence[dict[str, Any]],
    label: str,
    count: Callable[[int, int, str], str],
    robot: Callable[[dict[str, Any]], str],
) -> list[Figure]:
    """The two figures of the module docstring over robots measured by `separated_by_suggestion`.

    Parameters
    ----------
    outcomes : every robot measured (each with the keys `separated_by_suggestion` returns).
    label : the figures' names begin with it.
    count : (k, n, noun) -> the count beside a figure, e.g. '(2/3 robots, subset)'.
    robot : an outcome -> its short name in a figure's detail.
    """
    tied = [o for o in outcomes if o.get("ambiguous")]
    n_sep = sum(o["separated"] for o in tied)
    name = (
        f"{label}: tied forms told apart by the suggested run "
        f"{count(n_sep, len(tied), 'robots tied that a run can tell apart')}"
    )
    n_exact = sum(o["exact_after"] for o in tied)
    detail = (
        f"exactly right after the run: {n_exact}/{len(tied)}; "
        + "; ".join(
            f"{robot(o)}: {o['tied']} vs {o['tied_with']}, {o['suggested']}, "
            f"{'told apart' if o['separated'] else 'still tied'}"
            f"{', exactly right' if o['exact_after'] else ''}"
            for o in tied
        )[:300]
    )
    separated = (
        compare(name, 100.0 * n_sep / len(tied), "%", ">=", 100 * SEPARATED_TARGET, detail)
        if tied
        else info(name, math.nan, "%", NO_TIE)
    )
    same = [o for o in outcomes if o.get("equivalent")]
    same_count = count(len(same), len(outcomes), "robots")
    equivalent = info(
        f"{label}: tied forms the same on every run tried {same_count}",
        float(len(same)),
        "robots",
        "; ".join(f"{robot(o)}: {o['tied']} vs {o['tied_with']}" for o in same)[:300] or "none",
    )
    return [separated, equivalent]
