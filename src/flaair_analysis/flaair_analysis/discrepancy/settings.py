"""Decision rules and numerical settings of the discrepancy workflow."""

from __future__ import annotations

from dataclasses import dataclass

# ----------------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class Settings:
    """Decision rules and numerical settings (see the module docstring for the rules).

    Attributes
    ----------
    identify : fit the plant's own parameters first (`identification`) and fit each physics
        candidate jointly with the plant parameters it trades off against.
    decimate : keep every k-th sample in fits (noise stays white; 20 kHz -> 5 kHz).
    gap_noise_ratio : residual RMS / noise RMS above which a channel may have a gap.
    whiteness_alpha : Ljung-Box p-value below which the residual is not white.
    ljung_box_lags : lags of the Ljung-Box test.
    whiteness_decimate : decimation of the residual before the Ljung-Box test.
    min_heldout_drop : R1, relative drop of the held-out model error (above noise) an effect must
        bring.
    max_delta_bic : R2, held-out Delta-BIC must be below this.
    min_z : R3, distance of the parameter from its null value in standard errors.
    consistency_alpha : R4, p-value of the per-run scatter test below which an effect is refused.
    consistency_rel_tol : R4, allowance for model imperfection, as a fraction of the effect size.
    max_effects_per_channel : greedy steps per channel.
    pair_fallback : try pairs of effects on a channel when no single effect passes.
    max_nfev : function evaluations per least-squares fit.
    max_polish_rounds : further joint re-fits of a channel's parameters while a gap is left on it.
    polish_min_gain : relative cost drop a re-fit must bring for another round.
    band_edges_hz : drive-frequency bands of the localisation.
    window_s : window of the harmonic and worst-stretch analysis.
    xcorr_max_lag_s : largest residual-after-drive lag of the cross-correlation test.
    xcorr_z : |rho| sqrt(n) above which the cross-correlation with the drive is significant.
    discover : search the term library when the vocabulary leaves a located gap (`discovery`).
    max_discovered_terms : terms the discovery may add in all.
    discovery_shortlist : candidate terms per step judged on held-out runs (the best fits first).
    discovery_max_nfev : function evaluations of a shortlisted term's joint fit with the plant
        (the plant must move back from where the identification put it to mimic the term).
    discovery_composed_fits : composed forms per dynamics site fitted through the simulator
        after all of them are ranked by one linearized step (`term_candidates`).
    discovery_terms_per_channel : terms a channel may take (the second searched with the first
        in place, while the channel keeps a gap).
    discovery_skip_s : the first seconds of each run left out of a term's fits with the plant
        (a few wingbeats: the runs' initial states, fitted before the term was known, do not
        pull the coefficient there).
    discovery_polish_rounds : rounds of the final refit (the terms with the plant on the truth,
        then the runs' initial states), alternating towards their joint optimum.
    discovery_fd_step : multiplier of the finite-difference steps of the discovery's fits (the
        terms, the plant fitted along with them, the pitch plant refitted under a stroke term, the
        runs' initial states fitted on the sensors after a term). A
        term with sign() makes the simulated motion jump each time a zero crossing passes an
        integration stage: at the specs' own steps (1e-4 of the range, 1e-4 in log) the cost is
        rough and a fit stalls where it starts (stroke friction, draw 0: 15 % off, its cost 55 %
        above the truth's); at 30x the fit reaches the truth's cost (0.7 % off).
    """

    identify: bool = True
    decimate: int = 4
    gap_noise_ratio: float = 1.05
    whiteness_alpha: float = 1e-4
    ljung_box_lags: int = 20
    whiteness_decimate: int = 10
    min_heldout_drop: float = 0.20
    max_delta_bic: float = -10.0
    min_z: float = 5.0
    consistency_alpha: float = 1e-3
    consistency_rel_tol: float = 0.05
    max_effects_per_channel: int = 3
    pair_fallback: bool = True
    max_nfev: int = 40
    max_polish_rounds: int = 3
    polish_min_gain: float = 0.005
    band_edges_hz: tuple[float, ...] = (
        0.0,
        40.0,
        60.0,
        80.0,
        100.0,
        120.0,
        140.0,
        160.0,
        180.0,
        200.0,
        1e9,
    )
    window_s: float = 0.05
    xcorr_max_lag_s: float = 0.005
    xcorr_z: float = 5.0
    discover: bool = True
    max_discovered_terms: int = 2
    discovery_shortlist: int = 3
    discovery_max_nfev: int = 100
    discovery_composed_fits: int = 2
    discovery_terms_per_channel: int = 2
    discovery_skip_s: float = 0.03
    discovery_polish_rounds: int = 1
    discovery_fd_step: float = 30.0
