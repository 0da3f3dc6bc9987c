"""A frequency-response table as evidence (`TableEvidence`): each measured cell against the
plant's steady state, in units of its reading noise. Pure.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from flaair_analysis.evidence import Split
from flaair_model.model import Model
from flaair_model.settings import TableSettings

from .reader import PHASE_COLUMNS, Table
from .steady_state import steady_response

__all__ = [
    "TableEvidence",
    "normalised_residuals",
    "prediction_scores",
    "stack_cells",
    "table_scores",
]

_CLIP = 1e6  # a diverged model's cell


def _sigma(column: str, measured: np.ndarray, s: TableSettings) -> np.ndarray:
    if column in PHASE_COLUMNS:
        return np.full(measured.shape, s.phase_noise_deg)
    floor = s.reading_noise_deg / (2.0 if "amplitude" in column else 1.0)
    return np.hypot(floor, s.reading_noise_rel * measured)


def normalised_residuals(
    table: Table, response: dict[str, np.ndarray], s: TableSettings, columns: Sequence[str]
) -> dict[str, np.ndarray]:
    """Per column, (M, P) (model - measured) / reading noise; NaN where not measured."""
    out = {}
    for c in columns:
        meas = table.responses[c]
        diff = response[c] - meas
        if c in PHASE_COLUMNS:
            diff = (diff + 180.0) % 360.0 - 180.0
        out[c] = diff / _sigma(c, meas, s)
    return out


def stack_cells(table: Table, res: dict[str, np.ndarray]) -> np.ndarray:
    """(M, cells) of the measured cells of every column (a diverged model's as +-1e6)."""
    parts = [r[:, np.isfinite(table.responses[c])] for c, r in res.items()]
    stacked: np.ndarray = np.clip(
        np.nan_to_num(np.concatenate(parts, axis=1), nan=_CLIP), -_CLIP, _CLIP
    )
    return stacked


def prediction_scores(
    table: Table, pred: Mapping[str, np.ndarray], s: TableSettings
) -> tuple[dict[str, float], dict[str, float], int, float]:
    """`pred` ({column: one value per point}) against the table: per column noise ratio and
    NRMSE (phases wrapped), the cells and their chi-square.
    """
    cols = list(table.responses)
    res = normalised_residuals(table, {c: pred[c][None, :] for c in cols}, s, cols)
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
    return ratio, nrmse, int(cells.size), float(cells @ cells)


def table_scores(
    table: Table, model: Model, s: TableSettings
) -> tuple[dict[str, float], dict[str, float], int, float]:
    """The table against `model`: per column noise ratio and NRMSE, cells and chi-square."""
    resp = steady_response(
        [model], table.frequency_hz, table.drive_amplitude_v, table.drive_bias_v, s
    )
    return prediction_scores(table, {c: resp[c][0] for c in table.responses}, s)


class TableEvidence:
    """A table's `columns` as `flaair_analysis.evidence.Evidence` (no nuisance parameters: a
    table has no time axis and no initial state).
    """

    name = "table"
    n_nuisance = 0

    def __init__(self, table: Table, s: TableSettings, columns: Sequence[str]) -> None:
        self.table, self.settings = table, s
        self.sites = tuple(columns)

    def level_splits(self) -> list[tuple[str, TableEvidence, TableEvidence, np.ndarray]]:
        """Per drive level: its name, the other levels, the level, and its points' mask."""
        t, out = self.table, []
        for i, level in enumerate(t.levels_v):
            held = t.level_index == i
            rest = TableEvidence(t.subset(~held), self.settings, self.sites)
            part = TableEvidence(t.subset(held), self.settings, self.sites)
            out.append((f"{level:g} V", rest, part, held))
        return out

    def heldout(self) -> tuple[Split, ...]:
        """Leave one drive level out: each level judged by a model fitted on the others."""
        return tuple(Split(*parts) for parts in self.level_splits())

    def site_index(self) -> dict[str, np.ndarray]:
        """Per column, the positions of its measured cells in a residual row (`stack_cells`)."""
        out, at = {}, 0
        for c in self.sites:
            k = int(np.isfinite(self.table.responses[c]).sum())
            out[c], at = np.arange(at, at + k), at + k
        return out

    def nuisance_start(self) -> np.ndarray:
        """No nuisance parameters."""
        return np.zeros(0)

    def nuisance_steps(self) -> np.ndarray:
        """No nuisance parameters."""
        return np.zeros(0)

    def residuals(self, models: Sequence[Model], nuisance: np.ndarray) -> np.ndarray:
        """(m, cells) of the measured cells of its columns, one steady-state batch."""
        if not self.sites:
            return np.zeros((len(models), 0))
        t = self.table
        resp = steady_response(
            list(models), t.frequency_hz, t.drive_amplitude_v, t.drive_bias_v, self.settings
        )
        return stack_cells(t, normalised_residuals(t, resp, self.settings, self.sites))

    def linearised(
        self, models: Sequence[Model], nuisance: np.ndarray, h: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The rows of `models` (one batch) and an empty nuisance Jacobian."""
        rows = self.residuals(models, nuisance)
        return rows, np.zeros((rows.shape[1], 0))

    def stage_piece(self, side: str, channel: str) -> TableEvidence | None:
        """Its columns of `side` (None: it measures none)."""
        cols = [c for c in self.sites if c.startswith(side)]
        return TableEvidence(self.table, self.settings, cols) if cols else None

    def set_scores(self, model: Model) -> tuple[dict[str, float], dict[str, float], int, float]:
        """The whole table against `model` (`table_scores`)."""
        return table_scores(self.table, model, self.settings)
