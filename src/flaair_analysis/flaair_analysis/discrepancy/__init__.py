"""Model-vs-measurement discrepancy workflow, pure (numpy, scipy, numba via flaair_sim; no ROS,
no plots, no file I/O but the nominal model `offnominal` scales its terms by): the core of
`bin/flaair discrepancy` and `bin/flaair identify`, whose command lines and reports are
`flaair_tools.discrepancy`.

Modules: `runs` (runs, their initial state and simulation), `run_evidence` (runs as evidence for
the one fit: residuals in units of each channel's noise, each run's state a nuisance), `vocabulary`
(each effect registered once), `identification` (grey-box fit of the plant), `diagnosis` (where a
residual disagrees), `fitting` (least squares on folds), `effect_judging` (an effect candidate
judged by rules R1-R6), `search` (channel-by-channel search; `found` lists what it found, one entry
per effect), `evidence_search` (the search over any list of evidence: candidates ranked alone,
judged with the plant they trade off against on every piece's held-out splits, side by side; the
tables' search, `FreeParam` the one fitted-parameter type), `discovery` (terms from the library
`flaair_model.terms` where the vocabulary leaves a gap; `term_candidates` ranks the library's terms
and composed forms for it, `term_judging` judges a term against the plant refitted without it in
the same box, `discovery_uncertainty` the next best form and the experiment that tells them apart),
`workflow` (`analyse`: identify, search on top of the fitted plant, discover), `datasets` (the
fixed hidden-effect cases and their runs), `offnominal` (the randomized off-nominal robot
generator), `case` (one case), `scoring` (the workflow scored on the cases).
The decision rules' constants are `flaair_model.settings.DiscrepancySettings`, read from the
`discrepancy` section of config/flaair.yaml (as the tables' from its `tables` section) and passed
in: the workflow reads no file.

Given measured runs (drive, both sensor voltages, ground-truth angles) and a model, the core

1. simulates the model with each run's recorded drive and compares all four channels
   (``stroke_deg``, ``pitch_deg``, ``stroke_sensor_v``, ``pitch_sensor_v``);
2. localises the disagreement (`diagnose`): channel, frequency band, drive level (full vs half
   drive error ratio), harmonics, worst stretch of time, residual whiteness (Ljung-Box on the
   decimated residual) and cross-correlation with the drive (a residual correlated with the
   drive means a mis-modelled input path; a white, uncorrelated one is noise);
3. names the missing effects (`find_effects`): every vocabulary effect that can act on a channel
   is fitted by nonlinear least squares (`scipy.optimize.least_squares`, Jacobian by finite
   differences computed with `simulate_batch`), run by run; its evidence is judged on held-out
   runs; accepted effects are added greedily until nothing significant is left;
4. returns the input model with the found effects added, the gap before and after (per-channel
   NRMSE on held-out runs) and an honest status.

Signal path and order of analysis
---------------------------------
The four measured channels sit on a directed signal path, and each channel is analysed in turn,
upstream first, with only the effects that can act on it (`EFFECT_CHANNELS`)::

    drive -> stroke dynamics -> stroke_deg  (truth)   candidates: structural_damping, collision,
                                                       wing_damage
    stroke -> pitch dynamics -> pitch_deg   (truth)   candidates: hinge_stiffening (and the
                                                       stroke physics, in case only the pitch
                                                       truth shows it)
    stroke -> actuator sensor -> stroke_sensor_v      candidates: sensor_delay, charge_amp_highpass,
                                                       feedthrough, transmission_nonlinearity,
                                                       strain_transfer_loss (channel stroke)
    pitch  -> hinge sensor    -> pitch_sensor_v       candidates: sensor_delay, charge_amp_highpass,
                                                       strain_transfer_loss (channel pitch)

The ground-truth channels separate physics from sensor effects: sensor effects cannot change
``stroke_deg``/``pitch_deg``, so physics effects are judged on the truth channels alone (where an
unmodelled sensor effect cannot bias them), sensor effects on the sensor channels with the
physics already corrected. When a truth channel keeps an unexplained gap, the sensor channel
below it is judged *truth-referenced*: the sensor model is driven by the measured angle (model
angle + interpolated measured-minus-model error) instead of the simulated one, so a propagated
physics error is not blamed on the sensor; the pitch truth below an unexplained stroke gap is
not analysed (its gap is reported as possibly propagated). On the second sensor, the sensor
effects found on the first are tried first on both sensors at the same values (no new
parameter), then with this sensor's own value; a sensor effect found on both sensors with
consistent parameters becomes one effect with ``channel: both``, otherwise the model keeps one
value per sensor chain (``{stroke: {...}, pitch: {...}}``, `flaair_model.model.PerChannel`).
Sensor effects are tried without re-integrating the dynamics: the motion is simulated once and
`sensor_voltage` (the plant's sensor chain in numpy) does the rest.

Decision rules (`DiscrepancySettings`, all documented constants)
----------------------------------------------------------------
A channel *has a gap* when its residual RMS exceeds the noise estimate by more than
``gap_noise_ratio`` (noise from the median absolute second difference of the residual, which a
smooth model error barely touches) AND the decimated residual is not white (Ljung-Box p below
``whiteness_alpha``). Status ``no_discrepancy``: no channel has a gap with the input model.

Each candidate effect is fitted on each run alone (per-run estimates theta_r with standard
errors; a coarse grid, then least squares); the all-run estimate is their inverse-variance mean;
each run is predicted with the inverse-variance mean of the *other* runs' estimates
(leave-one-run-out; a single run is split into two halves). It is accepted only if ALL of:

* R1 held-out: the channel's model error above noise (pooled held-out RSS minus the noise's
  share, on the RMS scale: `flaair_analysis.evidence.judging`, the convention a table's held-out
  levels are judged by too) drops by more than ``min_heldout_drop``;
* R2 evidence: held-out Delta-BIC < ``max_delta_bic`` (BIC = sum over runs of
  n ln(RSS/n) + k ln N, Gaussian errors of unknown variance, on the held-out residuals);
* R3 significance: the all-run parameter is more than ``min_z`` standard errors from its null
  value (collision: the limit more than ``min_z`` SE below the largest stroke the model reaches)
  and inside its search range (an estimate stuck at a bound other than the null value is not a
  fit);
* R4 consistency: the per-run estimates agree (chi-square of their scatter about the mean, with
  each variance widened by (``consistency_rel_tol`` x effect size)^2, has p >=
  ``consistency_alpha``).
  Runs differ in drive level (full and half chirp) and in time, so an effect whose parameter
  would have to change with the drive level or over time (an effect outside the vocabulary that
  a vocabulary effect only mimics) is refused here;
* R5 (a sensor effect already found on the other sensor) decides its form, not its acceptance:
  where the two sensors' estimates agree within 3 combined standard errors + the R4 allowance it
  becomes one value on both chains, else each chain keeps its own;
* R6 (stroke physics judged on pitch_deg): stroke_deg keeps no gap with the effect added.

Among the passing candidates the lowest held-out BIC wins; the loop repeats on the channel (the
effects found there re-fitted jointly) until no gap is left, no candidate passes, or
``max_effects_per_channel`` is reached. If a gap is left, pairs of candidates are fitted jointly
(effects that mask each other, like a delay and a high-pass); a pair that passes every rule and
predicts the held-out runs better replaces the greedy choice.

Structural vs aerodynamic damping: a larger quadratic aerodynamic damping Gamma than the model's
is *not* the vocabulary's ``structural_damping`` (linear in velocity). A viscous damping ratio
fitted to it must shrink at half drive (the quadratic term's equivalent viscous damping scales
with stroke amplitude), so R4 refuses it and the case is reported ``unexplained`` at the stroke
channel near resonance, naming the refused damping ratio of each run (e.g. 0.083 at full drive,
0.058 at half drive for Gamma x1.6).

Status ``explained``: effects were added and no channel has a gap left (in-sample, final model);
``unexplained``: a gap remains (its channel, band, drive level and time stretch are reported).
``gap_before``/``gap_after`` are NRMSE per channel on held-out runs (after: effect parameters
re-fitted without the run they predict).

Effects already in the input model are kept as they are and are not offered as candidates.
"""

from __future__ import annotations

from .diagnosis import (
    ChannelGap,
    Diagnosis,
    bode_points,
    diagnose,
    noise_estimates,
    nrmse_by_channel,
)
from .discovery import Discovered, DiscoveryOutcome, discover
from .effect_judging import CandidateEvidence, FoundEffect
from .evidence_search import (
    Candidate,
    FreeParam,
    HeldOut,
    Judged,
    ParamFit,
    Side,
    fit_params,
    heldout,
    search_sides,
)
from .identification import PlantFit, identify_plant
from .run_evidence import RunEvidence
from .runs import (
    DiscrepancyInputError,
    Run,
    check_runs,
    initial_mechanical_state,
    measured_motion,
    mechanics_model,
    sensor_voltage,
    simulate_runs,
)
from .search import ChannelSearch, find_effects
from .vocabulary import (
    CHANNELS,
    EFFECT_CHANNELS,
    SENSOR_EFFECTS,
    STATUSES,
    VOCABULARY,
    EffectSpec,
    candidate_groups,
    candidate_specs,
)
from .workflow import DiscrepancyResult, analyse

__all__ = [
    "CHANNELS",
    "EFFECT_CHANNELS",
    "SENSOR_EFFECTS",
    "STATUSES",
    "VOCABULARY",
    "Candidate",
    "CandidateEvidence",
    "ChannelGap",
    "ChannelSearch",
    "Diagnosis",
    "Discovered",
    "DiscoveryOutcome",
    "DiscrepancyInputError",
    "DiscrepancyResult",
    "EffectSpec",
    "FoundEffect",
    "FreeParam",
    "HeldOut",
    "Judged",
    "ParamFit",
    "PlantFit",
    "Run",
    "RunEvidence",
    "Side",
    "analyse",
    "bode_points",
    "candidate_groups",
    "candidate_specs",
    "check_runs",
    "diagnose",
    "discover",
    "find_effects",
    "fit_params",
    "heldout",
    "identify_plant",
    "initial_mechanical_state",
    "measured_motion",
    "mechanics_model",
    "noise_estimates",
    "nrmse_by_channel",
    "search_sides",
    "sensor_voltage",
    "simulate_runs",
]
