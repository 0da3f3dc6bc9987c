"""The health monitor's change test: which of the robot's parts changed, how much and when. Pure.

Input, per wingbeat: the estimator's raw ratios to the model (`health.wingbeat_estimate`) of the
wing inertia r, the stroke film's gain a_s and the pitch film's gain a_p, and each film's zero
(the wingbeat's mean angle over its amplitude, `health.film_zeros`). The test watches five
series, chosen so that each cause moves few of them and their errors are nearly independent:

    r,   a_s,   q = a_p / a_s   (the pitch film's reading against the stroke film's; ratios)
    z_s, z_p                    (the films' zeros, in units of their amplitudes; differences)

The two films' gains share the error of the stroke's power balance (correlation 0.87 under the
dSA loop), which cancels in q: q scatters about half as much as a_s.

Causes (`CAUSES`, a table): each cause moves the watched series along a fixed signature
(d log ratio, or d zero, per unit of the cause, from the estimator's equations): the inertia
moves r; a stroke film gain moves a_s and q opposite; a pitch film gain moves q; an actuator
gain g is seen by both films at once (sqrt(g) each), so it moves a_s by half its log and q not at
all; a charge amplifier's offset moves its film's zero. Causes with the same signature cannot be
told apart from the films and the drive at one operating point, and an event names them
together (`alternatives`): a pitch film gain and the wing hinge's stiffness (both scale the
pitch reading against the stroke); an actuator gain and the stroke's damping (both scale the
drive's power balance); a wing inertia and the stroke's stiffness (the resonance shows only
K / I); an amplifier's offset and a constant torque on the stroke or a moved rest angle of the
hinge (both move the film's mean).

Test: estimates are averaged in pairs of consecutive wingbeats (successive wingbeats share
amplitudes through the stroke's log rate and their estimates anti-correlate; a pair's mean is
the test's sample). Per watched series a two-sided CUSUM on z = d / sigma, d = x / mu0 - 1 for a
ratio and x - mu0 for a zero, with mu0 and sigma (a pair mean's scatter, relative for a ratio,
at least `sigma_floor`) learned over a steady baseline window. The drift is half the smallest
move a `detect_change` of any cause makes on the series (for a zero: a `detect_change` of the
amplitude), so a change of that size or more accumulates and the model's misfit across
operating points (a few tenths of a per cent) does not. The threshold h of each series is
derived for `false_alarms_per_hour` over all series and both directions at the baseline's
wingbeat rate, from Siegmund's approximation of a CUSUM's in-control run length,

    ARL0(k, h) = (exp(2 k b) - 2 k b - 1) / (2 k^2),   b = h + 1.166   (k, h in sigmas),

which holds for independent normal samples (the pairs' residual correlation is negative, which
lengthens the run: the derived rate is an upper bound).
An alarm is confirmed once `confirm_wingbeats` estimates follow its change point; the watched
series' moves are their medians against mu0. A series moved if its move exceeds its drift and
`event_significance` standard errors of the pairs' scatter. An alarm with nothing moved stands
and is judged again at each pair, until a series has moved or its CUSUM returns to zero (the
K_r ramp's wingbeats scatter about no change and their CUSUM decays without an event; a small
change's first window may not be significant yet). The cause is the signature that fits the
moves best (weighted least squares in the log ratios and the zeros, each series weighted by its
baseline sigma); its size is the fitted magnitude: a ratio exp(size), or a zero's move in units
of the film's amplitude. After an event every baseline is learned again.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.optimize import brentq

from flaair_model.notes import INFO, Note

WATCHED = ("wing_inertia", "stroke_film_gain", "film_ratio", "stroke_film_zero", "pitch_film_zero")
RATIO = np.array([True, True, True, False, False])  # a ratio series (else a difference)
_N = len(WATCHED)
PAIR = 2  # estimates averaged into one sample of the test (module docstring)
_SIEGMUND_B = 1.166  # Siegmund's correction of the threshold for the overshoot (normal samples)
BASELINE_TEXT = "health baseline: "  # the note a learned baseline gives
# A saved baseline's ratios hold at its own operating point (a model misfit or a film lag reads
# differently at another frequency): a wingbeat whose frequency differs from the baseline's by
# more than this is not judged against it. The K_r ramp's synchronous lead (90 Hz against a
# ~145 Hz self-excited wing) is not; a 40 % inertia loss (+29 % in frequency) still is.
SAVED_BASELINE_BAND = 0.3


class Cause(NamedTuple):
    """A change the test can name: its signature on the watched series and its look-alikes."""

    name: str
    signature: tuple[float, ...]  # d (log r, log a_s, log q, z_s, z_p) per unit of the cause
    alternatives: tuple[str, ...]  # causes with the same signature (not told apart)
    is_ratio: bool = True  # its size is a log ratio (else a zero's move, in amplitudes)


CAUSES = (
    Cause("wing_inertia", (1.0, 0.0, 0.0, 0.0, 0.0), ("stroke_stiffness",)),
    Cause("stroke_film_gain", (0.0, 1.0, -1.0, 0.0, 0.0), ()),
    Cause("pitch_film_gain", (0.0, 0.0, 1.0, 0.0, 0.0), ("hinge_stiffness",)),
    Cause("actuator_gain", (0.0, 0.5, 0.0, 0.0, 0.0), ("stroke_damping",)),
    Cause("stroke_amplifier_offset", (0.0, 0.0, 0.0, 1.0, 0.0), ("stroke_bias",), False),
    Cause("pitch_amplifier_offset", (0.0, 0.0, 0.0, 0.0, 1.0), ("hinge_rest_angle",), False),
)
_SIGNATURES = np.array([c.signature for c in CAUSES])
# the smallest move a change of any cause makes on each watched series, per unit of its log
_SMALLEST_MOVE = np.array([np.min(np.abs(col[col != 0])) for col in _SIGNATURES.T], dtype=float)


class ChangeParams(NamedTuple):
    """The change test's settings (config/flaair.yaml `health_node`)."""

    warmup_wingbeats: int
    baseline_wingbeats: int
    detect_change: float  # the smallest relative change of a cause the drift lets accumulate
    false_alarms_per_hour: float
    sigma_floor: float
    confirm_wingbeats: int
    event_significance: float
    max_baseline_scatter: float


class Baseline(NamedTuple):
    """What the test judges against: each watched series' mean and a pair mean's scatter
    (relative for a ratio), at a wingbeat frequency. Learned in a run, or saved from a healthy
    run of the same robot and given at the start (`initial`).
    """

    mean: np.ndarray  # (5,) WATCHED
    sigma: np.ndarray  # (5,)
    frequency_hz: float


class ChangeState(NamedTuple):
    """Baseline sums, CUSUMs, change point, post-change estimates."""

    learned: int  # estimates in the baseline window so far (after the warm-up)
    skip: int  # estimates still to skip (warm-up)
    window: np.ndarray  # (baseline_wingbeats, 6) the last watched estimates and frequency
    mu: np.ndarray  # (5,) nan until learned
    sigma: np.ndarray  # (5,) a pair mean's scatter (relative for a ratio)
    drift: np.ndarray  # (5,) CUSUM drift k, sigmas
    threshold: np.ndarray  # (5,) CUSUM threshold h, sigmas
    half: np.ndarray  # (5,) the first estimate of a pair (nan: none)
    g_up: np.ndarray
    g_down: np.ndarray
    since: np.ndarray  # (5,) pairs since each CUSUM last left zero (0: at zero)
    alarm: np.ndarray  # (5,) bool
    history: np.ndarray  # (confirm, 5) last watched estimates, newest last
    frequency_hz: float = math.nan  # the baseline's wingbeat frequency
    given: bool = False  # the baseline was given (saved from another run), not learned here


class Change(NamedTuple):
    """A named change: cause, its size and stderr, the look-alikes.

    `size`: a ratio after / before (a gain, the inertia), or a film zero's move in units of the
    film's amplitude (an offset: `is_ratio` false).
    """

    cause: str
    size: float
    stderr: float
    alternatives: tuple[str, ...]
    is_ratio: bool


def initial(
    params: ChangeParams, skip: int | None = None, baseline: Baseline | None = None
) -> ChangeState:
    """`skip` (default the warm-up) estimates to skip, then a baseline to learn; or `baseline`
    given, judged against from the first estimate (the warm-up keeps a start's transient out of
    a baseline learned; the transient gate and the confirmation's median keep it out of an
    event).
    """
    z = np.zeros(_N)
    nan = np.full(_N, np.nan)
    state = ChangeState(
        0,
        (0 if baseline is not None else params.warmup_wingbeats) if skip is None else skip,
        np.full((params.baseline_wingbeats, _N + 1), np.nan),
        nan.copy(),
        nan.copy(),
        nan.copy(),
        nan.copy(),
        nan.copy(),
        z.copy(),
        z.copy(),
        np.zeros(_N, dtype=np.int64),
        np.zeros(_N, dtype=bool),
        np.full((params.confirm_wingbeats, _N), np.nan),
    )
    return state if baseline is None else _armed(state, baseline, params)[0]._replace(given=True)


def baseline_of(state: ChangeState) -> Baseline | None:
    """The baseline the test judges against now (None: not learned yet)."""
    if not np.isfinite(state.mu).all():
        return None
    return Baseline(state.mu.copy(), state.sigma.copy(), state.frequency_hz)


def watched(estimate: np.ndarray, zeros: np.ndarray) -> np.ndarray:
    """(5,) the watched series of a raw estimate (r, a_s, a_p, ...) and the films' zeros."""
    return np.array([estimate[0], estimate[1], estimate[2] / estimate[1], zeros[0], zeros[1]])


def _moves(x: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Each series' move from its baseline: relative for a ratio, a difference for a zero."""
    moves: np.ndarray = np.subtract(x, mu, dtype=float)
    # only the ratios are divided: a zero's baseline may be exactly 0
    np.divide(x, mu, out=moves, where=RATIO)
    moves[..., RATIO] -= 1.0
    return moves


def log_run_length(drift: float, threshold: float) -> float:
    """The log of a one-sided CUSUM's in-control run length in samples (Siegmund; sigmas)."""
    x = 2.0 * drift * (threshold + _SIEGMUND_B)
    if x < 1e-6:  # no drift: a random walk's exit time, b^2
        return 2.0 * math.log(threshold + _SIEGMUND_B)
    return x + math.log1p(-(x + 1.0) * math.exp(-x)) - math.log(2.0 * drift * drift)


def cusum_threshold(drift: float, run_length: float) -> float:
    """The threshold (sigmas) giving a one-sided CUSUM of drift `drift` the in-control run
    length `run_length` samples.
    """
    target = math.log(run_length)
    return float(brentq(lambda h: log_run_length(drift, h) - target, 0.0, 1e6))


def false_alarms_per_hour(state: ChangeState, frequency_hz: float) -> float:
    """The learned test's false-alarm rate at `frequency_hz` wingbeats a second (every series,
    both directions; nan before a baseline).
    """
    if not np.isfinite(state.mu).all():
        return math.nan
    samples_per_hour = 3600.0 * frequency_hz / PAIR
    return float(
        sum(
            2.0 * samples_per_hour / math.exp(log_run_length(k, h))
            for k, h in zip(state.drift, state.threshold, strict=True)
        )
    )


def _learn(
    state: ChangeState, x: np.ndarray, frequency_hz: float, params: ChangeParams
) -> tuple[ChangeState, list[Note]]:
    """One estimate into the baseline window; the baseline, its drifts and thresholds once the
    window is full and steady.
    """
    window = np.vstack([state.window[1:], np.r_[x, frequency_hz][None, :]])
    learned = min(state.learned + 1, params.baseline_wingbeats)
    state = state._replace(learned=learned, window=window)
    if learned < params.baseline_wingbeats:
        return state, []
    mu = window[:, :_N].mean(axis=0)
    scale = np.where(RATIO, np.abs(mu), 1.0)  # a ratio's scatter is relative, a zero's not
    scatter = window[:, :_N].std(axis=0) / scale
    f = window[:, _N]
    spread = (f.max() - f.min()) / f.mean()
    # Still settling (the self-excited amplitude after the K_r ramp, read through a misfit that
    # depends on it): the window's halves differ by more than the drift the CUSUM lets pass, and
    # a baseline learned there alarms once the estimates settle.
    half = window.shape[0] // 2
    trend = _moves(window[half:, :_N].mean(axis=0), window[:half, :_N].mean(axis=0))
    if not (
        np.all(scatter <= params.max_baseline_scatter)
        and spread <= params.max_baseline_scatter
        and np.all(np.abs(trend) <= params.detect_change * _SMALLEST_MOVE / 2.0)
    ):
        return state, []  # not steady yet: slide on
    n = window.shape[0] // PAIR * PAIR
    pairs = window[:n, :_N].reshape(-1, PAIR, _N).mean(axis=1)
    sigma = pairs.std(axis=0, ddof=1) / scale
    return _armed(state, Baseline(mu, sigma, float(f.mean())), params)


def _armed(
    state: ChangeState, baseline: Baseline, params: ChangeParams
) -> tuple[ChangeState, list[Note]]:
    """The test judging against `baseline`: its drifts, and its thresholds for the false-alarm
    rate at the baseline's wingbeat frequency.
    """
    mu = np.asarray(baseline.mean, dtype=float)
    sigma = np.maximum(np.asarray(baseline.sigma, dtype=float), params.sigma_floor)
    drift = params.detect_change * _SMALLEST_MOVE / 2.0 / sigma
    run_length = 2.0 * _N * 3600.0 * baseline.frequency_hz / PAIR / params.false_alarms_per_hour
    threshold = np.array([cusum_threshold(k, run_length) for k in drift])
    state = state._replace(
        mu=mu, sigma=sigma, drift=drift, threshold=threshold, frequency_hz=baseline.frequency_hz
    )
    text = BASELINE_TEXT + ", ".join(f"{n} {m:.3f}" for n, m in zip(WATCHED, mu, strict=True))
    text += f" (CUSUM h {', '.join(f'{h:.1f}' for h in threshold)} sigmas"
    text += f" for {params.false_alarms_per_hour:g} false alarm an hour)"
    return state, [Note(INFO, text, "")]


def step(
    state: ChangeState,
    estimate: np.ndarray,
    zeros: np.ndarray,
    frequency_hz: float,
    params: ChangeParams,
) -> tuple[ChangeState, list[Change], list[Note]]:
    """One wingbeat's raw estimate (r, a_s, a_p, ...) and films' zeros (`health.film_zeros`)
    through the baseline and the CUSUMs.
    """
    if state.given and abs(frequency_hz / state.frequency_hz - 1.0) > SAVED_BASELINE_BAND:
        return state, [], []  # another operating point than the saved baseline's: not judged
    x = watched(estimate, zeros)
    history = np.vstack([state.history[1:], x[None, :]])
    if state.skip > 0:
        return state._replace(skip=state.skip - 1, history=history), [], []
    if not np.isfinite(state.mu).all():
        state, notes = _learn(state._replace(history=history), x, frequency_hz, params)
        return state, [], notes
    if not np.isfinite(state.half).all():  # the first of a pair
        return state._replace(half=x, history=history), [], []
    z = _moves((state.half + x) / 2.0, state.mu) / state.sigma
    g_up = np.maximum(0.0, state.g_up + z - state.drift)
    g_down = np.maximum(0.0, state.g_down - z - state.drift)
    at_zero = (g_up == 0) & (g_down == 0)
    since = np.where(at_zero, 0, state.since + 1)
    alarm = state.alarm | (np.maximum(g_up, g_down) > state.threshold)
    state = state._replace(
        half=np.full(_N, np.nan),
        g_up=g_up,
        g_down=g_down,
        since=since,
        alarm=alarm & ~at_zero,
        history=history,
    )
    confirmed = state.alarm & (since * PAIR >= params.confirm_wingbeats)
    if not confirmed.any():
        return state, [], []
    post = _moves(history, state.mu)  # the last confirm_wingbeats estimates against the baseline
    move = np.median(post, axis=0)  # robust to the change's own transient wingbeats
    n = post.shape[0] // PAIR * PAIR
    pairs = post[-n:].reshape(-1, PAIR, _N).mean(axis=1) if n >= 2 * PAIR else post
    err = pairs.std(axis=0, ddof=1) / math.sqrt(pairs.shape[0])
    smallest = params.detect_change * _SMALLEST_MOVE / 2.0
    # moved by more than the drift, and by more than its own scatter allows: a transient's
    # estimates (the K_r ramp's) scatter widely, and their median is no change
    moved = np.abs(move) > np.maximum(smallest, params.event_significance * err)
    if not (confirmed & moved).any():  # not yet told from a transient: the alarm stands, test on
        return state, [], []
    y = np.where(RATIO, np.log1p(np.where(RATIO, move, 0.0)), move)
    change = name_change(y, state.sigma / math.sqrt(max(n // PAIR, 1)))
    return initial(params, skip=0), [change], []


def name_change(moves: np.ndarray, err: np.ndarray) -> Change:
    """The cause whose signature best fits the watched series' moves (log ratios, zeros'
    differences), by weighted least squares with standard errors `err`; its size and stderr.
    """
    w = 1.0 / np.square(err)
    best, best_chi2 = None, math.inf
    for cause, d in zip(CAUSES, _SIGNATURES, strict=True):
        info = float(np.sum(w * d * d))
        size = float(np.sum(w * d * moves)) / info
        chi2 = float(np.sum(w * np.square(moves - size * d)))
        if chi2 < best_chi2:
            best, best_chi2 = (cause, size, 1.0 / math.sqrt(info)), chi2
    assert best is not None
    cause, size, se = best
    if cause.is_ratio:
        ratio = math.exp(size)
        return Change(cause.name, ratio, ratio * se, cause.alternatives, True)
    return Change(cause.name, size, se, cause.alternatives, False)
