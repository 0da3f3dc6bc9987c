"""One hidden-effect case of the discrepancy datasets:
the true robot, its runs, what must be found.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["DatasetCase"]


@dataclass(frozen=True)
class DatasetCase:
    """One hidden-effect case.

    Attributes
    ----------
    name : unique case name.
    group : 'single', 'pair', 'null', 'outside' or 'confusable'.
    effects : vocabulary effects of the true robot, ((name, params), ...).
    outside : '' or one of OUTSIDE_KINDS (aero_damping: a Gamma change beyond the plant
        identification's fit range).
    outside_strength : its size (aero_damping: Gamma factor; sensor_gain_drift: gain lost over the
        session; second_resonance: mode gain relative to the stroke's static gain).
    noise_scale : noise relative to the model's noise section.
    seed : noise seed.
    note : what the case tests.
    plant_scale : ((plant key, factor), ...): the robot's plant differs from the model's.
    hidden : vocabulary effects the robot carries that a plant change reproduces exactly (not
        separable, e.g. wing_damage): the right answer does not name them.
    video_every : ground truth only every k-th sample (a video frame rate), NaN between; 1: DAQ
        rate.
    terms : physics outside the vocabulary that the term library can express
        (`flaair_model.terms.DiscoveredTerm`, ...): the right answer discovers each (its kind,
        acts_on and coefficient) and ends ``explained``.
    below_limit : the effects are below what the search on the fitted plant resolves (the joint fit
        absorbs them into the plant on the truth, and the sensors do not search physics): the right
        answer names nothing and leaves the gap located (``unexplained``).
    """

    name: str
    group: str
    effects: tuple[Any, ...] = ()
    outside: str = ""
    outside_strength: float = 0.0
    noise_scale: float = 1.0
    seed: int = 0
    note: str = ""
    plant_scale: tuple[Any, ...] = ()
    hidden: tuple[Any, ...] = ()
    video_every: int = 1
    below_limit: bool = False
    terms: tuple[Any, ...] = ()

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the hidden vocabulary effects, sorted."""
        return tuple(sorted(n for n, _ in self.effects))

    @property
    def expected_names(self) -> tuple[str, ...]:
        """Names the workflow must report, sorted (none for effects below the limit)."""
        return () if self.below_limit else self.effect_names

    @property
    def expected_status(self) -> str:
        """Status the workflow must report."""
        if self.outside or self.below_limit:
            return "unexplained"
        return "explained" if self.effects or self.terms else "no_discrepancy"

    @property
    def expected_gap_channel(self) -> str:
        """Channel where an outside case must leave its gap ('' otherwise)."""
        return {
            "aero_damping": "stroke_deg",
            "sensor_gain_drift": "pitch_sensor_v",
            "second_resonance": "stroke_deg",
        }.get(self.outside, "")

    @property
    def true_label(self) -> str:
        """Row label of the confusion table ('plant:' marks a hidden, not separable effect)."""
        below = "below:" if self.below_limit else ""
        parts = [below + n for n in self.effect_names] + [
            f"plant:{n}" for n in sorted(n for n, _ in self.hidden)
        ]
        if self.outside:
            parts.append(f"outside:{self.outside}")
        parts += [f"term:{t.kind}@{t.acts_on}" for t in self.terms]
        return "+".join(parts) or "none"

    @property
    def expected_found_label(self) -> str:
        """The confusion-table column a right answer falls in."""
        names = "+".join(self.expected_names) or "none"
        return names + (" (gap left)" if self.expected_status == "unexplained" else "")
