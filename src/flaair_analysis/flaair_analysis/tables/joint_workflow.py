"""The discrepancy workflow on runs and a table of the same robot (docs/TABLES.md). Pure.

What is joint and what is not:

1. The plant is fitted on both (`joint.identify_joint`): joint.
2. The search is the runs' workflow (`discrepancy.workflow.analyse`), started from the joint
   plant, judged on held-out runs: runs only. A table shows only what acts on the wing's
   motion and needs no time axis; the runs show that and the sensor chain.
3. What the runs' workflow found (effects, discovered terms) is judged on the table's held-out
   drive levels: each level predicted by the model with its plant refitted (table only, from the
   final model) on the other levels, effects as found. Kept when the table's held-out
   chi-square does not rise beyond its noise: by more than 2 sqrt(2 N) (two standard deviations
   of a chi-square of N cells: what noise alone moves it by). The runs have already shown the
   finding improves their held-out prediction, so this is "improves one, without worsening the
   other beyond noise". Refused otherwise: the model written is the joint plant alone, the
   status `unexplained`, and a note names what the table refused.
4. With a finding kept, the plant is refitted on both again with it in place (the effects' and
   terms' values stay as the runs' search fitted them).

Not joint: a candidate is not searched on the table, and the table's held-out levels do not
rank candidates; the table's own search (`tables.workflow`) is not run.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from flaair_analysis.discrepancy.runs import Run
from flaair_analysis.discrepancy.settings import Settings
from flaair_analysis.discrepancy.workflow import DiscrepancyResult, analyse
from flaair_model.model import Model
from flaair_model.settings import TableSettings

from .fit import PITCH_KEYS, STROKE_KEYS, normalised_residuals, plant_params, stack_cells
from .joint import JointFit, identify_joint
from .reader import Table
from .workflow import heldout_predictions

__all__ = ["JointDiscrepancy", "TableCheck", "analyse_joint", "table_heldout"]


@dataclass(frozen=True)
class TableCheck:
    """The table's held-out drive levels predicted by a model (plant refitted on the others).

    Attributes
    ----------
    noise_ratio, nrmse : {column: RMS residual / noise, RMS residual / RMS measured}.
    chi2, n : sum of squares of the noise-weighted held-out residuals, and the cells.
    """

    noise_ratio: dict[str, float]
    nrmse: dict[str, float]
    chi2: float
    n: int

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "noise_ratio": self.noise_ratio,
            "nrmse": self.nrmse,
            "chi2_per_cell": self.chi2 / max(self.n, 1),
            "cells": self.n,
        }


@dataclass(frozen=True)
class JointDiscrepancy:
    """Outcome of `analyse_joint`.

    Attributes
    ----------
    status : the runs' workflow's, or `unexplained` when the table refused its findings.
    joint : the plant fitted on both before the search.
    runs_result : the runs' workflow started from the joint plant.
    final : the plant refitted on both with the findings in place (None: nothing kept).
    model_out : what to write: `final`'s model, or the joint plant alone.
    table_before, table_after : the table's held-out levels, joint plant and model_out.
    kept : the findings passed the table's check (True when there was nothing to check).
    notes : what the table check decided, in words.
    """

    status: str
    joint: JointFit
    runs_result: DiscrepancyResult
    final: JointFit | None
    model_out: Model
    table_before: TableCheck
    table_after: TableCheck
    kept: bool
    notes: tuple[str, ...]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready summary of the joint parts (the runs' part is the runs' report)."""
        return {
            "status": self.status,
            "joint_identification": self.joint.as_dict(),
            "final_identification": self.final.as_dict() if self.final is not None else None,
            "table_heldout_before": self.table_before.as_dict(),
            "table_heldout_after": self.table_after.as_dict(),
            "table_chi2_allowance": _allowance(self.table_before.n),
            "findings_kept": self.kept,
            "notes": list(self.notes),
            "what_is_joint": "plant fitted on runs and table; search on the runs (held-out runs); "
            "findings checked on the table's held-out drive levels",
        }


def _allowance(n: int) -> float:
    """What noise alone moves a chi-square of n cells by (two standard deviations)."""
    return 2.0 * math.sqrt(2.0 * n)


def table_heldout(table: Table, model: Model, s: TableSettings) -> TableCheck:
    """Each level of `table` predicted by `model` with its plant refitted on the other levels."""
    cols = list(table.responses)
    keys = [
        *(STROKE_KEYS if any(c.startswith("stroke") for c in cols) else ()),
        *(PITCH_KEYS if any(c.startswith("pitch") for c in cols) else ()),
    ]
    if table.levels_v.size < 2:  # nothing to hold out: the model as it is
        from .steady_state import steady_response

        resp = steady_response(
            [model], table.frequency_hz, table.drive_amplitude_v, table.drive_bias_v, s
        )
        pred = {c: resp[c][0] for c in cols}
    else:
        quick = replace(s, max_nfev=s.heldout_max_nfev)
        pred = heldout_predictions(table, model, plant_params(model, keys, {}, 1.5), quick, cols)
    res = normalised_residuals(table, {c: v[None, :] for c, v in pred.items()}, s, cols)
    ratio, nrmse = {}, {}
    for c in cols:
        ok = np.isfinite(table.responses[c])
        if not ok.any():
            continue
        r = np.nan_to_num(res[c][0][ok], nan=1e6)
        ratio[c] = float(np.sqrt(np.mean(r**2)))
        meas = table.responses[c][ok]
        diff = pred[c][ok] - meas
        if "phase" in c:
            diff = (diff + 180.0) % 360.0 - 180.0
        nrmse[c] = float(np.sqrt(np.mean(diff**2)) / max(np.sqrt(np.mean(meas**2)), 1e-300))
    cells = stack_cells(table, res)[0]
    return TableCheck(ratio, nrmse, float(cells @ cells), int(cells.size))


def analyse_joint(
    runs: Sequence[Run],
    table: Table,
    model: Model,
    noise: Mapping[str, float],
    s: TableSettings,
    settings: Settings = Settings(),
    progress: Callable[[str], None] | None = None,
) -> JointDiscrepancy:
    """Plant on both, the runs' search from it, its findings checked on the table (docstring)."""
    if progress:
        progress("joint plant")
    joint = identify_joint(runs, table, model, noise, s, settings.decimate)
    result = analyse(joint.runs, joint.model, settings, progress=progress)
    if progress:
        progress("table check")
    before = table_heldout(table, joint.model, s)
    found = bool(result.effects or result.discovered)
    notes: list[str] = []
    if not found:
        notes.append("the runs' search added nothing: the model is the joint plant")
        return JointDiscrepancy(
            result.status, joint, result, None, joint.model, before, before, True, tuple(notes)
        )
    findings = replace(result.model_out, plant=joint.model.plant)
    after = table_heldout(table, findings, s)
    rise = after.chi2 - before.chi2
    names = [e.name for e in result.effects] + [
        f"{d.term.kind}@{d.term.acts_on}" for d in result.discovered
    ]
    if rise > _allowance(before.n):
        notes.append(
            f"the table refused the runs' findings ({', '.join(names)}): its held-out chi-square "
            f"rose by {rise:.1f} over {before.n} cells (noise allows {_allowance(before.n):.1f}); "
            "the model is the joint plant alone"
        )
        return JointDiscrepancy(
            "unexplained", joint, result, None, joint.model, before, after, False, tuple(notes)
        )
    change = "fell" if rise < 0 else "rose"
    notes.append(
        f"the table's held-out chi-square {change} by {abs(rise):.1f} over {before.n} cells with "
        f"the runs' findings ({', '.join(names)}; noise allows a rise of "
        f"{_allowance(before.n):.1f}): kept, the plant refitted on both with them"
    )
    final = identify_joint(runs, table, findings, noise, s, settings.decimate)
    after = table_heldout(table, final.model, s)
    return JointDiscrepancy(
        result.status, joint, result, final, final.model, before, after, True, tuple(notes)
    )
