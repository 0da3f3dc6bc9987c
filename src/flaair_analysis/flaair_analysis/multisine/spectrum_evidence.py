"""A multisine run set as evidence (`SpectrumEvidence`): the model's line spectra against the
measured ones, in units of the measured noise, for the one fit (`flaair_analysis.evidence`). Pure.

Each realization m is simulated from rest on its own logged drive; the transient periods are
dropped, as the analysis drops them, so no initial state is fitted (no nuisance parameters).
Per channel and line k of the band (excited, odd detection and even lines), the residual is
(Yhat_m(k) - Ybar_m(k)) / (sigma(k) / sqrt 2), its real and imaginary parts as two rows (each
carries half of a complex variance): Ybar_m the mean over the P periods, sigma^2 its noise
variance (`nld.ChannelFigures.sigma2`), pooled over the
realizations and over `POOL_LINES` neighbouring lines (a variance from P - 1 = 3 degrees of
freedom would make single lines' chi-squares heavy-tailed; noise is smooth in frequency).

A realization's nonlinear distortion is deterministic (its phases fix it), so a model with the
robot's physics predicts the detection lines too: the residual is noise where the model is right,
and the odd and even lines carry what `nld.disagreements` reads as the model's missing distortion.
Held out: each realization judged by a model fitted on the others.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.ndimage import uniform_filter1d

from flaair_analysis.evidence import Split
from flaair_analysis.multisine import nld, spectra
from flaair_analysis.multisine.analysis import VIDEO, FoundDesign, RunInput, channel_grid
from flaair_model.model import Model
from flaair_sim.core.plant import SimOutput, simulate_batch_from

__all__ = ["POOL_LINES", "SpectrumEvidence", "spectrum_channels"]

POOL_LINES = 5  # neighbouring lines whose noise variances are pooled into each line's
_CLIP = 1e6  # a diverged model's residual
_VARIANCE_FLOOR = 1e-12  # x the band's mean variance: a noise-free line cannot divide by zero


def _sim_channel(sim: SimOutput, name: str) -> np.ndarray:
    if name in ("stroke_deg", "pitch_deg"):
        return np.asarray(np.degrees(getattr(sim, name.replace("_deg", "_rad"))))
    return np.asarray(getattr(sim, name))


def spectrum_channels(
    runs: Sequence[RunInput], found: FoundDesign, wanted: Sequence[str]
) -> tuple[dict[str, spectra.VideoGrid | None], dict[str, str]]:
    """The channels of `wanted` the runs' spectra can be read on (a video channel on its frame
    grid, a sensor at every sample), and why each other one cannot.
    """
    n = found.period_samples
    first, count = found.transient_periods * n, found.periods * n
    usable: dict[str, spectra.VideoGrid | None] = {}
    skipped: dict[str, str] = {}
    for name in wanted:
        if name not in VIDEO:
            missing = [r.name for r in runs if name not in r.columns]
            if missing:
                skipped[name] = f"no {name} column in {missing[0]}"
            else:
                usable[name] = None
            continue
        got = channel_grid(runs, name, found, first, count)
        if isinstance(got, str):
            skipped[name] = got
        else:
            usable[name] = got
    return usable, skipped


class SpectrumEvidence:
    """A multisine run set's line spectra as `flaair_analysis.evidence.Evidence`.

    Parameters
    ----------
    runs
        One run per realization (measured-run columns, the drive logged).
    found
        The design the analysis found (`analysis.find_design`): N, lines, T, P.
    channels
        The channels compared, each with its video grid (None: every sample), as
        `spectrum_channels` gives them.
    """

    name = "spectra"
    n_nuisance = 0

    def __init__(
        self,
        runs: Sequence[RunInput],
        found: FoundDesign,
        channels: dict[str, spectra.VideoGrid | None],
        _keep: Sequence[int] | None = None,
        _sigma: dict[str, np.ndarray] | None = None,
    ) -> None:
        self.runs, self.found, self.grids = list(runs), found, dict(channels)
        self.sites = tuple(self.grids)
        n = found.period_samples
        self.first, self.count = found.transient_periods * n, found.periods * n
        self.lines = nld.line_sets(found.excited_lines).band
        self.keep = list(range(len(self.runs))) if _keep is None else list(_keep)
        self.drives = [
            np.asarray(self.runs[m].columns["drive_v"][: self.first + self.count], dtype=float)
            for m in self.keep
        ]
        self.ybar: dict[str, np.ndarray] = {}
        pooled: dict[str, np.ndarray] = {}
        for c, grid in self.grids.items():
            y = np.stack(
                [np.asarray(r.columns[c][: self.first + self.count], float) for r in self.runs]
            )
            figs = nld.ChannelFigures.of(
                spectra.line_spectra(y, self.first, found.periods, n, grid)
            )
            self.ybar[c] = figs.ybar[self.keep][:, self.lines]
            var = 0.5 * uniform_filter1d(figs.sigma2.mean(axis=0), POOL_LINES, mode="nearest")
            band = var[self.lines]
            pooled[c] = np.maximum(band, _VARIANCE_FLOOR * max(float(band.mean()), 1e-300))
        # per line, the standard deviation of a real or an imaginary part of Ybar
        self.sigma = {c: np.sqrt(v) for c, v in pooled.items()} if _sigma is None else _sigma

    def _part(self, keep: Sequence[int]) -> SpectrumEvidence:
        return SpectrumEvidence(self.runs, self.found, self.grids, keep, self.sigma)

    def only(self, sites: Sequence[str]) -> SpectrumEvidence:
        """The evidence of those of `sites` it sees (its noise kept)."""
        grids = {c: g for c, g in self.grids.items() if c in sites}
        sigma = {c: self.sigma[c] for c in grids}
        return SpectrumEvidence(self.runs, self.found, grids, self.keep, sigma)

    def stage_piece(self, side: str, channel: str) -> SpectrumEvidence | None:
        """Its spectrum of the side's video channel `channel` (None: not read)."""
        return self.only([channel]) if channel in self.sites else None

    def set_scores(self, model: Model) -> tuple[dict[str, float], dict[str, float], int, float]:
        """`scores` where it is fitted: the video channels (its films check findings, not the
        plant).
        """
        return self.only(VIDEO).scores(model)

    def scores(self, model: Model) -> tuple[dict[str, float], dict[str, float], int, float]:
        """`model` against the spectra: per channel the residual RMS over the noise and the NRMSE
        (RMS |Yhat - Ybar| over RMS |Ybar|, over the band's lines), the residual count, the
        chi-square.
        """
        yhat = self.model_spectra([model])
        ratio, nrmse, n, chi2 = {}, {}, 0, 0.0
        for c in self.sites:
            diff = yhat[c][0] - self.ybar[c]
            z = (diff / self.sigma[c]).ravel()
            r = np.concatenate([z.real, z.imag])
            ratio[c] = float(np.sqrt(np.mean(r * r)))
            nrmse[c] = float(
                np.sqrt(
                    np.mean(np.abs(diff) ** 2) / max(np.mean(np.abs(self.ybar[c]) ** 2), 1e-300)
                )
            )
            n, chi2 = n + r.size, chi2 + float(r @ r)
        return ratio, nrmse, n, chi2

    def heldout(self) -> tuple[Split, ...]:
        """Leave one realization out (none with a single realization)."""
        if len(self.keep) < 2:
            return ()
        return tuple(
            Split(
                self.runs[m].name,
                self._part([j for j in self.keep if j != m]),
                self._part([m]),
                m,
            )
            for m in self.keep
        )

    def site_index(self) -> dict[str, np.ndarray]:
        """Per channel, the positions of its lines' real and imaginary parts in a residual row."""
        out, at = {}, 0
        for c in self.sites:
            k = 2 * int(self.ybar[c].size)
            out[c], at = np.arange(at, at + k), at + k
        return out

    def nuisance_start(self) -> np.ndarray:
        """No nuisance parameters (the transient is dropped, not fitted)."""
        return np.zeros(0)

    def nuisance_steps(self) -> np.ndarray:
        """No nuisance parameters."""
        return np.zeros(0)

    def model_spectra(self, models: Sequence[Model]) -> dict[str, np.ndarray]:
        """Per channel, (len(models), realizations, lines) of each model's mean line spectrum."""
        fs, n, p = self.found.fs_hz, self.found.period_samples, self.found.periods
        out: dict[str, list[np.ndarray]] = {c: [] for c in self.sites}
        for drive in self.drives:
            sim = simulate_batch_from(drive, fs, list(models), np.zeros(4))
            for c, grid in self.grids.items():
                spec = spectra.line_spectra(_sim_channel(sim, c), self.first, p, n, grid)
                out[c].append(spec.mean(axis=1)[:, self.lines])
        return {c: np.stack(v, axis=1) for c, v in out.items()}

    def residuals(self, models: Sequence[Model], nuisance: np.ndarray) -> np.ndarray:
        """(m, 2 x channels x realizations x lines): real and imaginary parts over the noise."""
        if not self.sites:
            return np.zeros((len(models), 0))
        yhat = self.model_spectra(models)
        parts = []
        for c in self.sites:
            z = (yhat[c] - self.ybar[c][None]) / self.sigma[c]
            z = z.reshape(len(models), -1)
            parts.extend([z.real, z.imag])
        rows = np.nan_to_num(np.hstack(parts), nan=_CLIP, posinf=_CLIP, neginf=-_CLIP)
        return np.asarray(np.clip(rows, -_CLIP, _CLIP))

    def linearised(
        self, models: Sequence[Model], nuisance: np.ndarray, h: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The rows of `models` (one batch per realization) and an empty nuisance Jacobian."""
        rows = self.residuals(models, nuisance)
        return rows, np.zeros((rows.shape[1], 0))
