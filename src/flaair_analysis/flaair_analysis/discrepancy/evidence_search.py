"""The search for missing effects and terms over any list of evidence (`search_sides`). Pure.

A candidate (a vocabulary effect, a library term) is a few `FreeParam`s. On each side (stroke,
then pitch) with a held-out gap (a site above `gap_ratio` x its noise):

1. every candidate is fitted alone on the side's evidence, from the best of its grid (one
   batch), within `heldout_max_nfev` evaluations: its chi-square ranks it;
2. the best `shortlist` are fitted again jointly with the side's plant parameters they trade off
   against (x/÷ 1.5, freed over x/÷ `fit_range` where one ends on that box's edge) and judged on
   every piece's held-out splits (each part predicted by the model fitted on the rest): kept
   when the side's error above noise drops by more than `min_heldout_drop` and the parameter
   lies `min_z` standard errors from doing nothing (`flaair_analysis.evidence.judging`);
3. vocabulary effects are judged first, the terms where no effect passes or the best one that
   passes still leaves the side a held-out gap; the lowest held-out error of all that pass
   wins, is added, the later sides' plant refitted under it, and the search goes on.

The evidence is whatever `Evidence` the caller gives per side (a table's columns, a multisine
set's spectra, runs): the search sees only residuals in units of noise, held-out splits and the
sites each residual belongs to.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from flaair_analysis.evidence import (
    Evidence,
    EvidenceFit,
    Split,
    distance_from_null,
    drop_failure,
    excess_above_noise,
    fit_evidence,
    gap_drop,
    passes_drop,
    passes_z,
    z_failure,
)
from flaair_model.model import Model
from flaair_model.settings import TableSettings

from .fitting import apply_values
from .vocabulary import PLANT_PARAMETERS, EffectSpec

__all__ = [
    "FIT_TOL",
    "PLANT_STEP",
    "TRADE_OFF_BOX",
    "Candidate",
    "FreeParam",
    "HeldOut",
    "Judged",
    "ParamFit",
    "SearchOutcome",
    "Side",
    "as_param_fit",
    "fit_params",
    "fit_space",
    "heldout",
    "plant_params",
    "search_sides",
    "setter",
    "values_at",
    "with_values",
]

PLANT_STEP = 1e-4  # forward-difference step of a plant parameter (log space)
TRADE_OFF_BOX = 1.5  # a candidate's plant parameters fitted within x/÷ this of their start
FIT_TOL = 1e-8  # the least-squares x, f and gradient tolerances (fit_evidence's default)


@dataclass(frozen=True)
class FreeParam:
    """A fitted parameter: the one parameter type (`EffectSpec`: a plant key, an effect's
    parameter or a term's coefficient, its bounds, fit space and step) and the value a fit
    starts it from.
    """

    spec: EffectSpec
    start: float

    @property
    def key(self) -> str:
        """The parameter's address (`EffectSpec.address`): `plant.<key>`, `effect.<name>.<key>`,
        `term.<kind>@<site>`.
        """
        return self.spec.address

    @property
    def lower(self) -> float:
        """Lower bound (the parameter's unit)."""
        return self.spec.lower

    @property
    def upper(self) -> float:
        """Upper bound (the parameter's unit)."""
        return self.spec.upper

    def bounded(self, start: float, lower: float, upper: float) -> FreeParam:
        """The parameter started at `start` within [lower, upper]."""
        return FreeParam(replace(self.spec, lower=lower, upper=upper), start)


@dataclass(frozen=True)
class ParamFit:
    """A fit's outcome: the model, each parameter's value and standard error, the residuals.

    `singular`: the evidence cannot determine the parameters apart (the Jacobian's rank is below
    their number): standard errors are infinite and correlations NaN, never a made-up matrix.
    `chi2` and `n` are summed over the pieces.
    """

    model: Model
    params: tuple[FreeParam, ...]
    values: dict[str, float]
    stderr: dict[str, float]
    correlation: np.ndarray
    chi2: float
    n: int
    nfev: int
    singular: bool = False


def plant_params(
    model: Model, keys: Sequence[str], start: Mapping[str, float], r: float
) -> list[FreeParam]:
    """Log-space `FreeParam`s for plant keys, within x/÷ `r` of `start` (or the model's value)."""
    out = []
    for k in keys:
        v = float(start.get(k, getattr(model.plant, k)))
        v = v if math.isfinite(v) and v > 0 else 1e-3 * float(getattr(model.plant, k) or 1.0)
        spec = EffectSpec(
            "plant", k, PLANT_PARAMETERS[k], v, v / r, v * r, (), PLANT_STEP, log=True,
            tested=False,
        )  # fmt: skip
        out.append(FreeParam(spec, v))
    return out


def with_values(model: Model, params: Sequence[FreeParam], values: Mapping[str, float]) -> Model:
    """`model` with each of `params` at `values[param.key]` (the one `apply_values`)."""
    return apply_values(model, [p.spec for p in params], [values[p.key] for p in params])


def fit_space(params: Sequence[FreeParam]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The start, lower and upper bounds and steps of `params` in fit space."""
    return (
        np.array([p.spec.to_fit(p.start) for p in params]),
        np.array([p.spec.to_fit(p.lower) for p in params]),
        np.array([p.spec.to_fit(p.upper) for p in params]),
        np.array([p.spec.step for p in params]),
    )


def values_at(params: Sequence[FreeParam], x: np.ndarray) -> dict[str, float]:
    """Each parameter's value (its unit) at the fit-space point `x`."""
    return {p.key: p.spec.from_fit(float(v)) for p, v in zip(params, x, strict=True)}


def setter(model: Model, params: Sequence[FreeParam]) -> Callable[[np.ndarray], Model]:
    """Fit space -> `model` with `params` at those values."""
    return lambda x: with_values(model, params, values_at(params, x))


def as_param_fit(model: Model, params: Sequence[FreeParam], fit: EvidenceFit) -> ParamFit:
    """`fit_evidence`'s outcome of `params` (from `model`) as a `ParamFit`."""
    values = values_at(params, fit.x)
    se = np.sqrt(np.diag(fit.covariance))
    stderr = {
        p.key: float(values[p.key] * e if p.spec.log else e * p.spec.unit)
        for p, e in zip(params, se, strict=True)
    }
    return ParamFit(
        with_values(model, params, values),
        tuple(params),
        values,
        stderr,
        fit.correlation,
        float(sum(fit.chi2)),
        int(sum(fit.n)),
        fit.nfev,
        fit.singular,
    )


def fit_params(
    pieces: Sequence[Evidence], model: Model, params: Sequence[FreeParam], max_nfev: int
) -> ParamFit:
    """Least squares of `params` (from `model`) over `pieces` (`fit_evidence`)."""
    x0, lower, upper, steps = fit_space(params)
    fit = fit_evidence(
        pieces, setter(model, params), [x0], lower, upper, steps, max_nfev=max_nfev, tol=FIT_TOL
    )
    return as_param_fit(model, params, fit)


@dataclass(frozen=True)
class HeldOut:
    """Every piece's held-out splits judged: per site the RMS of the parts' noise-weighted
    residuals (None: the site has none), and each split with the fit it was judged by.
    """

    ratio: dict[str, float | None]
    fits: tuple[tuple[Split, ParamFit], ...]

    def excess(self, sites: Sequence[str]) -> float:
        """The error above noise of `sites` (`evidence.excess_above_noise`)."""
        return excess_above_noise(v * v for c in sites if (v := self.ratio.get(c)) is not None)


def heldout(
    pieces: Sequence[Evidence], model: Model, params: Sequence[FreeParam], max_nfev: int
) -> HeldOut:
    """Each part of each piece's held-out splits predicted by `params` fitted (from `model`) on
    the rest of that piece.
    """
    ss: dict[str, float] = {}
    count: dict[str, int] = {}
    fits = []
    for piece in pieces:
        for split in piece.heldout():
            fit = fit_params([split.fit], model, params, max_nfev)
            part = split.judged
            rows = part.residuals([fit.model], part.nuisance_start())[0]
            for site, idx in part.site_index().items():
                r = rows[idx]
                ss[site] = ss.get(site, 0.0) + float(r @ r)
                count[site] = count.get(site, 0) + int(idx.size)
            fits.append((split, fit))
    ratio = {
        c: float(math.sqrt(ss[c] / count[c])) if count.get(c) else None
        for piece in pieces
        for c in piece.sites
    }
    return HeldOut(ratio, tuple(fits))


@dataclass(frozen=True)
class Candidate:
    """An effect or a term as the search fits it."""

    name: str  # effect name, or `kind@site` of a term
    is_term: bool
    side: str  # the `Side` it is judged on
    params: tuple[FreeParam, ...]
    null: tuple[float, ...]
    grid: tuple[float, ...]  # starts of the first parameter
    trades_off: tuple[str, ...]  # plant keys fitted along with it


@dataclass
class Judged:
    """A candidate's outcome: its fit on all of the side's evidence, its held-out error and the
    rules.
    """

    candidate: Candidate
    fit: ParamFit
    heldout_error: float
    drop: float
    z: float
    failed: list[str] = field(default_factory=list)
    heldout_ratio: dict[str, float | None] = field(default_factory=dict)  # site -> noise ratio


@dataclass(frozen=True)
class Side:
    """One side of the search: the evidence its candidates are fitted and judged on.

    Attributes
    ----------
    name : "stroke" or "pitch".
    pieces : its evidence (only the side's sites).
    plant_keys : its plant parameters (refitted on it after an earlier side's finding).
    """

    name: str
    pieces: tuple[Evidence, ...]
    plant_keys: tuple[str, ...]

    @property
    def sites(self) -> tuple[str, ...]:
        """The sites its evidence sees."""
        return tuple(dict.fromkeys(c for p in self.pieces for c in p.sites))


@dataclass(frozen=True)
class SearchOutcome:
    """What `search_sides` found: the model, the candidates kept and every one judged, and the
    held-out judgement of the model with them.
    """

    model: Model
    accepted: tuple[Judged, ...]
    tried: tuple[Judged, ...]
    final: HeldOut


def _at(params: Sequence[FreeParam], values: Mapping[str, float], r: float) -> list[FreeParam]:
    """`params` restarted at the values of a fit (plant ones within x/÷ r)."""
    out = []
    for p in params:
        v = values.get(p.key, p.start)
        if p.spec.is_plant:
            out.append(p.bounded(v, v / r, v * r))
        else:
            out.append(replace(p, start=v))
    return out


def _grid_best(pieces: Sequence[Evidence], model: Model, cand: Candidate) -> FreeParam:
    """The candidate's first parameter started at the best of its grid (one batch)."""
    starts = [replace(cand.params[0], start=g) for g in cand.grid] or [cand.params[0]]
    models = [
        with_values(model, params, {p.key: p.start for p in params})
        for params in ((p0, *cand.params[1:]) for p0 in starts)
    ]
    cost = sum(
        (piece.residuals(models, piece.nuisance_start()) ** 2).sum(axis=1) for piece in pieces
    )
    return starts[int(np.argmin(cost))]


def _rank(side: Side, model: Model, cand: Candidate, s: TableSettings) -> tuple[float, Candidate]:
    """The side's chi-square with the candidate fitted alone (grid start), and the candidate
    started where that fit ended.
    """
    params = (_grid_best(side.pieces, model, cand), *cand.params[1:])
    try:
        fit = fit_params(side.pieces, model, params, s.heldout_max_nfev)
    except (ValueError, np.linalg.LinAlgError):  # the candidate drives the model unstable
        return math.inf, cand
    moved = tuple(replace(p, start=fit.values[p.key]) for p in params)
    return fit.chi2, replace(cand, params=moved)


def _judge(
    side: Side,
    model: Model,
    cand: Candidate,
    s: TableSettings,
    before: float,
    reach_deg: Callable[[Model], float],
) -> Judged:
    params = [*cand.params, *plant_params(model, cand.trades_off, {}, TRADE_OFF_BOX)]
    fit = fit_params(side.pieces, model, params, s.max_nfev)
    # fitted without the effect, the plant may have run far to mimic it (a hinge stiffening's
    # pitch fit at 1.9 x the robot's pitch frequency, the couplings at 4 x): a plant parameter
    # ending on the narrow box's edge is freed over the fit's whole range, from where it ended
    # (a wide box from the start sends a collision's joint fit to another minimum)
    if any(
        p.spec.is_plant and not (p.lower * 1.01 < fit.values[p.key] < p.upper / 1.01)
        for p in params
    ):
        wide = [
            replace(p, start=fit.values[p.key])
            for p in [*cand.params, *plant_params(model, cand.trades_off, {}, s.fit_range)]
        ]
        refit = fit_params(side.pieces, model, wide, s.max_nfev)
        if refit.chi2 < fit.chi2:
            params, fit = wide, refit
    held = heldout(side.pieces, model, _at(params, fit.values, TRADE_OFF_BOX), s.heldout_max_nfev)
    err = held.excess(side.sites)
    drop = gap_drop(before, err)
    key = cand.params[0].key
    v, se, null = fit.values[key], fit.stderr[key], cand.null[0]
    # a stop: its limit must lie below the stroke the model reaches
    reach = reach_deg(fit.model) if math.isinf(null) else math.inf
    z = distance_from_null(v, se, null, reach)
    failed = []
    if not passes_drop(drop, s.rules):
        failed.append(drop_failure(drop, s.rules))
    if not passes_z(z, s.rules):
        failed.append(z_failure(z, s.rules))
    return Judged(cand, fit, err, drop, z, failed, {c: held.ratio.get(c) for c in side.sites})


def _error(j: Judged) -> float:
    return j.heldout_error


def _leaves_gap(j: Judged, s: TableSettings) -> bool:
    """Whether the side keeps a gap on held-out parts with the candidate in the model."""
    return any((v or 0.0) > s.gap_ratio for v in j.heldout_ratio.values())


def _values_of(model: Model, keys: Sequence[str], accepted: Sequence[Judged]) -> dict[str, float]:
    out: dict[str, float] = {f"plant.{k}": getattr(model.plant, k) for k in keys}
    for j in accepted:
        for p in j.candidate.params:
            out[p.key] = j.fit.values[p.key]
    return out


def search_sides(
    sides: Sequence[Side],
    whole: Sequence[Evidence],
    model: Model,
    plant_free: Sequence[FreeParam],
    start: HeldOut,
    pool: Callable[[Model, str], Sequence[Candidate]],
    s: TableSettings,
    reach_deg: Callable[[Model], float] = lambda model: 90.0,
) -> SearchOutcome:
    """The forward selection of the module docstring, side by side.

    Parameters
    ----------
    sides
        In order, each side's evidence and plant keys.
    whole
        The evidence of every site: the model judged on its held-out splits after each finding.
    model
        The identified plant.
    plant_free
        The plant parameters refitted in each held-out split.
    start
        `model` judged on `whole` (`heldout` of `plant_free`).
    pool
        (model, side name) -> the candidates to try.
    reach_deg
        The largest stroke amplitude a model reaches on the evidence (a stop's R3).
    """
    keys = [k for side in sides for k in side.plant_keys]
    current, final = model, start
    accepted: list[Judged] = []
    tried: list[Judged] = []
    for i, side in enumerate(sides):
        sites = side.sites
        for _ in range(s.max_effects_per_side):
            if not sites or all((final.ratio.get(c) or 0.0) <= s.gap_ratio for c in sites):
                break
            before = final.excess(sites)
            candidates = list(pool(current, side.name))
            passed: list[Judged] = []
            for group in (False, True):  # vocabulary effects first, then terms
                if passed and not _leaves_gap(min(passed, key=_error), s):
                    break
                ranked = sorted(
                    (_rank(side, current, c, s) for c in candidates if c.is_term == group),
                    key=lambda rc: rc[0],
                )
                judged = [
                    _judge(side, current, c, s, before, reach_deg)
                    for cost, c in ranked[: s.shortlist]
                    if math.isfinite(cost)
                ]
                tried.extend(judged)
                passed += [j for j in judged if not j.failed]
            if not passed:
                break
            best = min(passed, key=_error)
            accepted.append(best)
            current = best.fit.model
            for later in sides[i + 1 :]:
                if later.pieces:
                    current = fit_params(
                        later.pieces,
                        current,
                        plant_params(current, later.plant_keys, {}, TRADE_OFF_BOX),
                        s.max_nfev,
                    ).model
            free = [*plant_free, *(p for j in accepted for p in j.candidate.params)]
            final = heldout(
                whole,
                current,
                _at(free, _values_of(current, keys, accepted), TRADE_OFF_BOX),
                s.max_nfev,
            )
    return SearchOutcome(current, tuple(accepted), tuple(tried), final)
