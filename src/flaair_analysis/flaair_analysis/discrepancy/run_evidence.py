"""Measured runs as evidence (`RunEvidence`): each channel's residual, demeaned per run, in units
of the channel's noise, with each run's initial angle and rate as nuisance parameters. Pure.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import cast

import numpy as np

from flaair_analysis.evidence import Split
from flaair_model.model import Model
from flaair_sim.core.plant import SimOutput, simulate_batch_from

from .fitting import make_folds
from .runs import Run

__all__ = ["STATE_STEP_RAD", "RunEvidence"]

STATE_STEP_RAD = 1e-4  # finite-difference step of the initial angle (and rate / omega)
_SIDE_STATES = {"stroke": (0, 1), "pitch": (2, 3)}
_CLIP = 1e6  # a diverged model's residual


def _sim_channel(sim: SimOutput, c: str) -> np.ndarray:
    """(m, n) record of channel `c` (degrees or volts) of a batch simulation."""
    if c == "stroke_deg":
        return cast(np.ndarray, np.degrees(sim.stroke_rad))
    if c == "pitch_deg":
        return cast(np.ndarray, np.degrees(sim.pitch_rad))
    return cast(np.ndarray, getattr(sim, c))


class RunEvidence:
    """Runs of one robot as `flaair_analysis.evidence.Evidence`.

    Parameters
    ----------
    runs
        Checked runs (`check_runs`), each with its measured initial state (`mechanical0`).
    noise
        Noise RMS per channel (degrees or volts): the residuals' unit.
    decimate
        Keep every k-th sample (the noise stays white).
    channels
        The measured channels compared (the sites it sees).
    side
        "stroke" or "pitch": each run's (angle, rate / omega) of that side is a nuisance
        parameter; None: no nuisance (the runs' states stay as measured).
    omega_rad_s
        The side's natural angular frequency (the rate's scale in fit space).
    windows
        Per run, the sample range [start, stop) compared (default: the whole run; the run is
        simulated from its start either way).
    """

    name = "runs"

    def __init__(
        self,
        runs: Sequence[Run],
        noise: Mapping[str, float],
        decimate: int,
        channels: Sequence[str],
        side: str | None = None,
        omega_rad_s: float = 1.0,
        windows: Sequence[tuple[int, int]] | None = None,
    ) -> None:
        self.runs = list(runs)
        self.sites = tuple(channels)
        self.noise, self.decimate, self.side = dict(noise), decimate, side
        self.sigma = {c: max(float(noise[c]), 1e-12) for c in self.sites}
        self.windows = list(windows) if windows is not None else [(0, r.n) for r in self.runs]
        self.idx = []
        for run, (start, stop) in zip(self.runs, self.windows, strict=True):
            sl = np.arange(0, run.n, decimate)
            sl = sl[(sl >= start) & (sl < stop)]
            self.idx.append({c: sl[np.isfinite(run.channel(c)[sl])] for c in self.sites})
        self.base = [
            np.zeros(4) if r.mechanical0 is None else np.asarray(r.mechanical0, float)
            for r in self.runs
        ]
        self.comp = _SIDE_STATES[side] if side else None
        self.omega = float(omega_rad_s)
        self.n_nuisance = 2 * len(self.runs) if side else 0

    def _part(self, windows: dict[int, tuple[int, int]]) -> RunEvidence:
        """The evidence of the runs in `windows` (run index: sample range)."""
        keep = sorted(windows)
        return RunEvidence(
            [self.runs[j] for j in keep],
            self.noise,
            self.decimate,
            self.sites,
            self.side,
            self.omega,
            [windows[j] for j in keep],
        )

    def heldout(self) -> tuple[Split, ...]:
        """Leave one run out (`fitting.make_folds`; a lone run's halves, each judged by a model
        fitted on the other).
        """
        folds = make_folds(self.runs)
        out = []
        for f in folds:
            rest = {g.run: (g.start, g.stop) for g in folds if g is not f}
            out.append(Split(f.name, self._part(rest), self._part({f.run: (f.start, f.stop)}), f))
        return tuple(out)

    def site_index(self) -> dict[str, np.ndarray]:
        """Per channel, the positions of its samples in a residual row (run by run)."""
        parts: dict[str, list[np.ndarray]] = {c: [] for c in self.sites}
        at = 0
        for idx in self.idx:
            for c in self.sites:
                k = int(idx[c].size)
                parts[c].append(np.arange(at, at + k))
                at += k
        return {c: np.concatenate([np.zeros(0, int), *v]) for c, v in parts.items()}

    def nuisance_start(self) -> np.ndarray:
        """Each run's measured (angle, rate / omega) of the side."""
        if self.comp is None:
            return np.zeros(0)
        a, b = self.comp
        return np.array([v for x in self.base for v in (x[a], x[b] / self.omega)])

    def nuisance_steps(self) -> np.ndarray:
        """`STATE_STEP_RAD` for every nuisance parameter."""
        return np.full(self.n_nuisance, STATE_STEP_RAD)

    def state(self, nuisance: np.ndarray, j: int) -> np.ndarray:
        """Run j's initial state [phi, phi', psi, psi'] at the nuisance parameters."""
        x = self.base[j].copy()
        if self.comp is not None:
            x[self.comp[0]] = nuisance[2 * j]
            x[self.comp[1]] = nuisance[2 * j + 1] * self.omega
        return x

    def runs_at(self, nuisance: np.ndarray) -> list[Run]:
        """The runs with their initial states at the nuisance parameters."""
        return [replace(r, mechanical0=self.state(nuisance, j)) for j, r in enumerate(self.runs)]

    def run_rows(self, j: int, models: Sequence[Model], x0: np.ndarray) -> np.ndarray:
        """(m, n_j) residual rows of run j from the initial states x0 ((m, 4))."""
        run, idx = self.runs[j], self.idx[j]
        parts = []
        sim = None
        for c in self.sites:
            i = idx[c]
            if i.size == 0:
                continue
            if sim is None:
                sim = simulate_batch_from(run.drive_v, run.fs_hz, list(models), x0)
            r = run.channel(c)[i][None, :] - _sim_channel(sim, c)[:, i]
            r = np.nan_to_num((r - r.mean(axis=1, keepdims=True)) / self.sigma[c], nan=_CLIP)
            parts.append(np.clip(r, -_CLIP, _CLIP))
        return np.hstack(parts) if parts else np.zeros((len(models), 0))

    def rows_from(self, models: Sequence[Model], states: Sequence[np.ndarray]) -> np.ndarray:
        """(m, n) rows of every run; states[j]: (m, 4) initial state of each model on run j."""
        return np.hstack(
            [self.run_rows(j, models, np.asarray(x0)) for j, x0 in enumerate(states)]
            or [np.zeros((len(models), 0))]
        )

    def residuals(self, models: Sequence[Model], nuisance: np.ndarray) -> np.ndarray:
        """(m, n) rows of every run at the nuisance parameters."""
        m = len(models)
        return self.rows_from(
            models, [np.tile(self.state(nuisance, j), (m, 1)) for j in range(len(self.runs))]
        )

    def linearised(
        self, models: Sequence[Model], nuisance: np.ndarray, h: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rows of `models` and the first model's Jacobian in each run's (angle, rate), one
        batch per run: the models, then the first one twice from the moved states.
        """
        m = len(models)
        rows, blocks = [], []
        for j in range(len(self.runs)):
            moved = []
            if self.comp is not None:
                for c in (2 * j, 2 * j + 1):
                    v = nuisance.copy()
                    v[c] += h[c]
                    moved.append(self.state(v, j))
            x0 = np.array([self.state(nuisance, j)] * m + moved)
            out = self.run_rows(j, [*models, *([models[0]] * len(moved))], x0)
            rows.append(out[:m])
            jac = np.zeros((out.shape[1], self.n_nuisance))
            for k, c in enumerate((2 * j, 2 * j + 1)[: len(moved)]):
                jac[:, c] = (out[m + k] - out[0]) / h[c]
            blocks.append(jac)
        if not rows:
            return np.zeros((m, 0)), np.zeros((0, self.n_nuisance))
        return np.hstack(rows), np.vstack(blocks)
