"""Documents and the report of the table workflow (discrepancy.json, identification.json,
report.html and its figures). A shell module: matplotlib and Jinja2 are imported here only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from flaair_model.model import Model

from .fit import TableFit
from .reader import Table, summarise

__all__ = ["identification_doc", "json_ready", "table_doc"]

INSEPARABLE_CORRELATION = 0.95
UNDETERMINED_REL_SE = 0.10


def json_ready(x: Any) -> Any:
    """Numpy scalars and arrays as plain numbers and lists; non-finite numbers as null."""
    if isinstance(x, dict):
        return {str(k): json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_ready(v) for v in x]
    if isinstance(x, np.ndarray):
        return json_ready(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def table_doc(table: Table) -> dict[str, Any]:
    """The table's summary: levels, frequencies, responses, the peak per level."""
    return {
        "name": table.name,
        "source": table.source,
        "points": table.n_points,
        "drive_levels_v": table.levels_v,
        "frequency_range_hz": [table.frequency_hz.min(), table.frequency_hz.max()],
        "responses": {c: int(np.isfinite(v).sum()) for c, v in table.responses.items()},
        "peaks": [s.__dict__ for s in summarise(table)],
    }


def identification_doc(
    table: Table,
    model_in: Model,
    fitted: Model,
    fits: Sequence[TableFit],
    start: dict[str, float],
    notes: Sequence[str],
) -> dict[str, Any]:
    """identification.json: each plant parameter (value, nominal, start, stderr, change), each
    stage's correlation matrix, the pairs the table cannot separate, notes.
    """
    params: dict[str, Any] = {}
    inseparable: list[str] = []
    stages = []
    for fit in fits:
        keys = [p.key.removeprefix("plant.") for p in fit.params]
        for p, k in zip(fit.params, keys, strict=True):
            v, nom = fit.values[p.key], float(getattr(model_in.plant, k))
            se = fit.stderr[p.key]
            params[k] = {
                "value": v,
                "nominal": nom,
                "start": start.get(k, p.start),
                "stderr": se,
                "relative_change": v / nom - 1.0 if nom else None,
            }
            if not se < UNDETERMINED_REL_SE * abs(v):
                inseparable.append(f"{k}: relative standard error {se / abs(v):.0%}")
        for i in range(len(keys)):
            for j in range(i + 1, len(keys)):
                if abs(fit.correlation[i, j]) > INSEPARABLE_CORRELATION:
                    inseparable.append(
                        f"{keys[i]} and {keys[j]}: correlation {fit.correlation[i, j]:+.3f}"
                    )
        stages.append(
            {
                "order": keys,
                "matrix": fit.correlation,
                "chi2_per_cell": fit.chi2 / max(fit.n_cells, 1),
                "cells": fit.n_cells,
                "evaluations": fit.nfev,
            }
        )
    return {
        "table": table_doc(table),
        "parameters": params,
        "correlation": stages,
        "inseparable": inseparable,
        "notes": list(notes),
        "plant_out": {k: getattr(fitted.plant, k) for k in params},
    }
