"""Typed accessors of config/flaair.yaml for the tools that read a section not their own.

A node reads its own section through its `ParamSpec` schema (typed, ranged); offline code that
needs a node's values (replay, the stroke study, a node's own I/O helpers) reads them through
`node_section` with that same schema, so they are checked as the running node checks them. A tool
that needs another section's values (the shared stream settings, the bridge's lead, `live`'s own
settings) reads them here, each section through one function returning a frozen dataclass: a
missing key or a value of the wrong type is a `ConfigError` naming the file, section and key.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from typing import Any, TypeVar

from flaair_model.config import ConfigError, config_dir, node_parameters, shared_parameters
from flaair_model.schema import ParameterError, ParamSpec

__all__ = [
    "BridgeSettings",
    "ControllerSettings",
    "DiscrepancySettings",
    "JudgingRules",
    "LiveSettings",
    "MonitorSettings",
    "StreamSettings",
    "TableSettings",
    "bridge",
    "controller",
    "discrepancy",
    "judging",
    "live",
    "monitor",
    "node_section",
    "read_section",
    "stream",
    "tables",
]

CONFIG_FILE = "flaair.yaml"
T = TypeVar("T")


@dataclass(frozen=True)
class StreamSettings:
    """The `/**` section: what every block stream shares."""

    sample_rate_hz: float
    block_size: int
    drive_limit_v: float


@dataclass(frozen=True)
class LiveSettings:
    """`bin/flaair live`: the composed loop's DDS
    batching, block size against a target, patience.
    """

    dds_batch_blocks: int
    target_block_size: int
    first_packet_timeout_s: float


@dataclass(frozen=True)
class BridgeSettings:
    """What a graph's launcher needs of the UDP bridge's section."""

    lead_samples: int
    realtime_priority: int


@dataclass(frozen=True)
class MonitorSettings:
    """What an experiment needs of the collision monitor's section."""

    min_wingbeat_hz: float


@dataclass(frozen=True)
class ControllerSettings:
    """The dSA controller's stream settings (its section over `/**`)."""

    sample_rate_hz: float
    block_size: int


@dataclass(frozen=True)
class JudgingRules:
    """The rules every candidate is judged by, whatever the evidence (`judging` section): runs,
    tables and spectra alike (`flaair_analysis.evidence.judging`).

    Attributes
    ----------
    min_heldout_drop : relative drop of the held-out model error above noise a candidate must
        bring, on the RMS scale: 1 - sqrt(excess after / excess before), the excess being the
        mean square of the noise-weighted residuals above 1.
    min_z : distance of its parameter from doing nothing, in standard errors.
    """

    min_heldout_drop: float
    min_z: float


@dataclass(frozen=True)
class DiscrepancySettings:
    """The discrepancy workflow on runs (`discrepancy` section): its decision rules (documented in
    `flaair_analysis.discrepancy`) and numerical settings.

    Attributes
    ----------
    identify : fit the plant's own parameters first (`identification`) and fit each physics
        candidate jointly with the plant parameters it trades off against.
    decimate : keep every k-th sample in fits (noise stays white; 20 kHz -> 5 kHz).
    gap_noise_ratio : residual RMS / noise RMS above which a channel may have a gap.
    whiteness_alpha : Ljung-Box p-value below which the residual is not white.
    ljung_box_lags : lags of the Ljung-Box test.
    whiteness_decimate : decimation of the residual before the Ljung-Box test.
    rules : R1 (`min_heldout_drop`) and R3 (`min_z`), the rules every kind of evidence shares.
    max_delta_bic : R2, held-out Delta-BIC must be below this.
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
    discovery_composed_fits : composed forms per site fitted through the simulator
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

    identify: bool
    decimate: int
    gap_noise_ratio: float
    whiteness_alpha: float
    ljung_box_lags: int
    whiteness_decimate: int
    rules: JudgingRules = field(metadata={"section": "judging"})
    max_delta_bic: float
    consistency_alpha: float
    consistency_rel_tol: float
    max_effects_per_channel: int
    pair_fallback: bool
    max_nfev: int
    max_polish_rounds: int
    polish_min_gain: float
    band_edges_hz: tuple[float, ...]
    window_s: float
    xcorr_max_lag_s: float
    xcorr_z: float
    discover: bool
    max_discovered_terms: int
    discovery_shortlist: int
    discovery_max_nfev: int
    discovery_composed_fits: int
    discovery_terms_per_channel: int
    discovery_skip_s: float
    discovery_polish_rounds: int
    discovery_fd_step: float


@dataclass(frozen=True)
class TableSettings:
    """Frequency-response tables (`tables` section): steady state, noise, hold-out rules (`rules`:
    the ones every kind of evidence shares, from the `judging` section).
    """

    sample_rate_hz: float
    settle_s: float
    measure_wingbeats: int
    min_frequency_hz: float
    max_frequency_hz: float
    reading_noise_deg: float
    reading_noise_rel: float
    phase_noise_deg: float
    fit_range: float
    max_nfev: int
    heldout_max_nfev: int
    shortlist: int
    max_effects_per_side: int
    near_resonance: float
    gap_ratio: float
    rules: JudgingRules = field(metadata={"section": "judging"})


def _convert(value: Any, kind: Any, where: str) -> Any:
    if typing.get_origin(kind) is tuple:  # tuple[float, ...]: a YAML list of numbers
        if not isinstance(value, list) or not value:
            raise ConfigError(f"{where}: must be a list of numbers, got {value!r}")
        return tuple(_convert(v, typing.get_args(kind)[0], where) for v in value)
    if kind is bool:
        if isinstance(value, bool):
            return value
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif kind is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif kind is str and isinstance(value, str):
        return value
    raise ConfigError(f"{where}: must be {kind.__name__}, got {value!r}")


def read_section(section: str, cls: type[T], file_name: str = CONFIG_FILE) -> T:
    """`cls` (a frozen dataclass) filled from `section`
    of config/`file_name`, each field checked; a field whose metadata names a section is that
    section's dataclass (one set of values several sections share).
    """
    values = (
        shared_parameters(file_name) if section == "/**" else node_parameters(file_name, section)
    )
    hints = typing.get_type_hints(cls)
    out = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if "section" in f.metadata:
            out[f.name] = read_section(f.metadata["section"], hints[f.name], file_name)
            continue
        where = f"{config_dir() / file_name}: {section}.{f.name}"
        if f.name not in values:
            raise ConfigError(f"{where}: missing")
        out[f.name] = _convert(values[f.name], hints[f.name], where)
    return cls(**out)


def stream() -> StreamSettings:
    """Sample rate, block size and drive limit of every block stream (`/**`)."""
    return read_section("/**", StreamSettings)


def live() -> LiveSettings:
    return read_section("live", LiveSettings)


def bridge() -> BridgeSettings:
    return read_section("bridge_node", BridgeSettings)


def monitor() -> MonitorSettings:
    return read_section("collision_monitor_node", MonitorSettings)


def controller() -> ControllerSettings:
    return read_section("dsa_controller_node", ControllerSettings)


def judging() -> JudgingRules:
    """The rules every candidate is judged by, on any evidence."""
    return read_section("judging", JudgingRules)


def discrepancy() -> DiscrepancySettings:
    """The discrepancy workflow on runs: its decision rules and numerical settings."""
    return read_section("discrepancy", DiscrepancySettings)


def tables() -> TableSettings:
    """`identify` and `discrepancy` on tables, `import-table`."""
    return read_section("tables", TableSettings)


def node_section(
    specs: list[ParamSpec], section: str, file_name: str = CONFIG_FILE
) -> dict[str, Any]:
    """A node's values from `section` of config/`file_name`, checked against its `specs` as the node
    checks them (type, range, choices), plus the shared `/**` values it inherits.

    Raises
    ------
    ParameterError
        Naming the file, section and parameter when one is missing or refused.
    """
    try:
        values = dict(node_parameters(file_name, section))
    except ConfigError as exc:
        raise ParameterError(str(exc)) from exc
    for spec in specs:
        where = f"{config_dir() / file_name}: {section}.{spec.name}"
        if spec.name not in values:
            raise ParameterError(f"{where}: missing")
        value = values[spec.name]
        try:
            if spec.type is list:
                if not isinstance(value, list):
                    raise ConfigError(f"{where}: must be a list of numbers, got {value!r}")
                value = [_convert(v, float, where) for v in value]
            else:
                value = _convert(value, spec.type, where)
        except ConfigError as exc:
            raise ParameterError(str(exc)) from exc
        if spec.type in (int, float) and (
            (spec.min_value is not None and value < spec.min_value)
            or (spec.max_value is not None and value > spec.max_value)
        ):
            raise ParameterError(
                f"{where}: {value!r} is outside [{spec.min_value}, {spec.max_value}]"
            )
        if spec.choices and value not in spec.choices:
            raise ParameterError(f"{where}: {value!r} is not one of {', '.join(spec.choices)}")
        values[spec.name] = value
    return values
