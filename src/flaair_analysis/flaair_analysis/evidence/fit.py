"""One least-squares fit over any list of evidence (`fit_evidence`). Pure: numpy, scipy.

The fitted parameters (plant keys, effect parameters, term coefficients: whatever `to_model`
maps a fit-space vector to) are shared by every piece of evidence; each piece adds its own
nuisance parameters (a run's initial angle and rate). The residual vector is every piece's rows
in units of its own noise, stacked: the sum of the pieces' chi-squares (maximum likelihood when
each noise model is right), so a run set's thousands of samples do not outvote a table's sixty
cells where they say nothing.

A piece whose chi-square per residual ends above `birge_refit` (a noise model too optimistic, or
physics the model misses) would outvote the others by its size alone: with `birge_refit` set,
each piece is then weighted by 1 / max(1, its Birge ratio) and the fit run once more from there.

The Jacobian is by forward differences, the step's sign flipped at an upper bound. Evidence with
nuisance parameters is linearised in one batch with the residual (a run's simulation of every
column at once costs little more than one); without any, the residual is evaluated alone and
the columns on demand (a trial step the solver rejects costs one model, not p + 1).

The covariance is s^2 (J^T J)^-1 by the SVD of the weighted Jacobian at the optimum, with s^2 =
max(1, chi-square per degree of freedom) (never more precise than the noise model says); a
Jacobian of rank below the parameters' number (`RANK_TOL`) gives infinite variances and NaN
correlations, never a made-up matrix.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from flaair_model.model import Model

from .protocol import Evidence

__all__ = ["RANK_TOL", "EvidenceFit", "covariance", "fit_evidence"]

RANK_TOL = 1e-9  # a singular value below this x the largest: a direction the evidence does not see


@dataclass(frozen=True)
class EvidenceFit:
    """The outcome of `fit_evidence`.

    Attributes
    ----------
    x : (p,) the fitted parameters (fit space).
    covariance : (p, p) their covariance (fit space); inf on the diagonal when `singular`.
    correlation : (p, p); NaN when `singular`.
    singular : the evidence cannot tell the parameters apart (rank below their number).
    nuisance : each piece's fitted nuisance parameters (fit space).
    chi2, n : each piece's unweighted chi-square and residual count at the optimum.
    weights : each piece's weight in the last fit (1, or 1 / its Birge ratio).
    start_costs : the unweighted chi-square at each start tried (the best one started the fit).
    nfev : residual evaluations by the solver.
    """

    x: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    singular: bool
    nuisance: tuple[np.ndarray, ...]
    chi2: tuple[float, ...]
    n: tuple[int, ...]
    weights: tuple[float, ...]
    start_costs: tuple[float, ...]
    nfev: int

    @property
    def cost(self) -> float:
        """The unweighted chi-square over every piece at the optimum."""
        return float(sum(self.chi2))


def covariance(jac: np.ndarray, scale: float) -> tuple[np.ndarray, bool]:
    """The parameters' covariance `scale` (J^T J)^-1 by the SVD of `jac`, and whether it is
    singular (fewer rows than columns, or a direction not seen): then every variance is infinite.
    """
    k = jac.shape[1]
    if jac.shape[0] >= k and np.isfinite(jac).all():
        if k == 0:
            return np.zeros((0, 0)), False
        _, sv, vt = np.linalg.svd(jac, full_matrices=False)
        if sv[-1] > RANK_TOL * sv[0]:
            cov: np.ndarray = (vt.T / sv**2) @ vt * scale
            return cov, False
    cov = np.full((k, k), np.nan)
    np.fill_diagonal(cov, np.inf)
    return cov, True


class _Stacked:
    """The pieces' residuals and Jacobian at a fit-space point (shared parameters, then each
    piece's nuisance), weighted, with the last point's evaluation kept.
    """

    def __init__(
        self,
        pieces: Sequence[Evidence],
        to_model: Callable[[np.ndarray], Model],
        p: int,
        steps: np.ndarray,
        upper: np.ndarray,
    ) -> None:
        self.pieces, self.to_model, self.p = list(pieces), to_model, p
        sizes = [int(e.n_nuisance) for e in self.pieces]
        self.offsets = (np.r_[0, np.cumsum(sizes)].astype(int) + p).tolist()
        self.h = np.concatenate(
            [np.asarray(steps, float)] + [np.asarray(e.nuisance_steps(), float) for e in pieces]
        )
        self.hi = np.r_[np.asarray(upper, float), np.full(sum(sizes), np.inf)]
        self.joint = sum(sizes) > 0
        self.weights = np.ones(len(self.pieces))
        self._full: dict[bytes, tuple[list[np.ndarray], np.ndarray]] = {}
        self._rows: dict[bytes, list[np.ndarray]] = {}

    def nuisance(self, u: np.ndarray, i: int) -> np.ndarray:
        """Piece i's nuisance parameters in u."""
        return u[self.offsets[i] : self.offsets[i + 1]]

    def _models(self, u: np.ndarray, h: np.ndarray) -> list[Model]:
        p = self.p
        return [self.to_model(u[:p] + h[c] * np.eye(p)[c]) for c in range(p)]

    def linearised(self, u: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
        """Each piece's rows at u and the unweighted Jacobian of all of them."""
        key = u.tobytes()
        if key not in self._full:
            self._full.clear()
            p, h = self.p, np.where(u + self.h > self.hi, -self.h, self.h)
            models = [self.to_model(u[:p]), *self._models(u, h)]
            rows_all, jacs = [], []
            for i, e in enumerate(self.pieces):
                lo, hi = self.offsets[i], self.offsets[i + 1]
                rows, jac_nuis = e.linearised(models, self.nuisance(u, i), h[lo:hi])
                jac = np.zeros((rows.shape[1], u.size))
                jac[:, :p] = ((rows[1:] - rows[0]) / h[:p, None]).T
                jac[:, lo:hi] = jac_nuis
                rows_all.append(rows[0])
                jacs.append(jac)
            self._full[key] = (rows_all, np.vstack([np.zeros((0, u.size)), *jacs]))
        return self._full[key]

    def rows(self, u: np.ndarray) -> list[np.ndarray]:
        """Each piece's unweighted rows at u."""
        if self.joint:
            return self.linearised(u)[0]
        key = u.tobytes()
        if key not in self._rows:
            self._rows.clear()
            model = self.to_model(u[: self.p])
            self._rows[key] = [
                e.residuals([model], self.nuisance(u, i))[0] for i, e in enumerate(self.pieces)
            ]
        return self._rows[key]

    def _row_weights(self, rows: list[np.ndarray]) -> np.ndarray:
        return np.concatenate(
            [np.zeros(0)]
            + [np.full(r.size, math.sqrt(w)) for r, w in zip(rows, self.weights, strict=True)]
        )

    def fun(self, u: np.ndarray) -> np.ndarray:
        """The weighted residual vector at u."""
        rows = self.rows(u)
        out: np.ndarray = np.concatenate([np.zeros(0), *rows]) * self._row_weights(rows)
        return out

    def jacobian(self, u: np.ndarray) -> np.ndarray:
        """The weighted Jacobian at u."""
        if self.joint:
            rows, jac = self.linearised(u)
        else:
            rows = self.rows(u)
            h = np.where(u + self.h > self.hi, -self.h, self.h)
            models = self._models(u, h)
            base = np.concatenate([np.zeros(0), *rows])
            moved = np.hstack(
                [np.zeros((self.p, 0))]
                + [e.residuals(models, self.nuisance(u, i)) for i, e in enumerate(self.pieces)]
            )
            jac = ((moved - base[None, :]) / h[: self.p, None]).T
        out: np.ndarray = jac * self._row_weights(rows)[:, None]
        return out

    def chi2(self, u: np.ndarray) -> list[float]:
        """Each piece's unweighted chi-square at u."""
        return [float(r @ r) for r in self.rows(u)]


def fit_evidence(
    evidence: Sequence[Evidence],
    to_model: Callable[[np.ndarray], Model],
    starts: Sequence[np.ndarray],
    lower: np.ndarray,
    upper: np.ndarray,
    steps: np.ndarray,
    *,
    max_nfev: int,
    tol: float = 1e-8,
    birge_refit: float | None = None,
) -> EvidenceFit:
    """Least squares of the shared parameters and each piece's nuisance over `evidence`.

    Parameters
    ----------
    evidence
        The pieces (`Evidence`), each giving residual rows in units of its noise.
    to_model
        Fit-space parameter vector (p,) -> the model it stands for.
    starts
        Candidate starts (p,) in fit space (clipped to the bounds); the one of lowest chi-square
        (at the pieces' nuisance starts) starts the fit.
    lower, upper, steps
        (p,) bounds and forward-difference steps in fit space.
    max_nfev, tol
        The solver's evaluations per fit and its x, f and gradient tolerances.
    birge_refit
        When set, a piece whose chi-square per residual exceeds it after the fit has the fit
        repeated with each piece weighted by 1 / max(1, its Birge ratio) (module docstring).
    """
    pieces = list(evidence)
    p = int(np.size(lower))
    st = _Stacked(pieces, to_model, p, steps, upper)
    n_nuis = st.offsets[-1] - p
    lo = np.r_[np.asarray(lower, float), np.full(n_nuis, -np.inf)]
    x_nuis = np.concatenate([np.zeros(0)] + [np.asarray(e.nuisance_start(), float) for e in pieces])
    candidates = [np.r_[np.clip(np.asarray(s, float), lo[:p], st.hi[:p]), x_nuis] for s in starts]
    start_costs = [sum(st.chi2(u)) for u in candidates]
    u = candidates[int(np.argmin(start_costs))]
    nfev = 0
    for attempt in range(2):
        sol = least_squares(
            st.fun, u, jac=st.jacobian, bounds=(lo, st.hi), method="trf", max_nfev=max_nfev,
            xtol=tol, ftol=tol, gtol=tol,
        )  # fmt: skip
        u, nfev = sol.x, nfev + int(sol.nfev)
        if birge_refit is None or attempt:
            break
        ratio = [c / max(r.size, 1) for c, r in zip(st.chi2(u), st.rows(u), strict=True)]
        if max(ratio, default=0.0) <= birge_refit:
            break
        st.weights[:] = [1.0 / max(1.0, r) for r in ratio]
    f = st.fun(u)
    cov_all, singular = covariance(st.jacobian(u), max(1.0, float(f @ f) / max(f.size - u.size, 1)))
    cov = cov_all[:p, :p]
    se = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se, se)
    return EvidenceFit(
        x=u[:p].copy(),
        covariance=cov,
        correlation=corr,
        singular=singular,
        nuisance=tuple(st.nuisance(u, i).copy() for i in range(len(pieces))),
        chi2=tuple(st.chi2(u)),
        n=tuple(int(r.size) for r in st.rows(u)),
        weights=tuple(float(w) for w in st.weights),
        start_costs=tuple(float(c) for c in start_costs),
        nfev=nfev,
    )
