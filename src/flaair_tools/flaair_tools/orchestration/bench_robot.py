"""The simulated bench robot the experiments and the demo run (config/experiments.yaml `robot:`):
its plant off nominal, its hidden vocabulary effects and its discovered terms.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from flaair_model.config import config_dir, load_yaml

__all__ = ["robot_effects", "robot_model", "robot_section", "write_robot_model"]


def robot_section() -> dict[str, Any]:
    """The simulated bench robot (config/experiments.yaml `robot:`): plant factors, effects,
    discovered terms, video frame spacing.
    """
    document = load_yaml(config_dir() / "experiments.yaml") or {}
    return dict(document.get("robot") or {})


def robot_effects() -> dict[str, dict[str, Any]]:
    """The hidden vocabulary effects of the simulated bench robot."""
    return dict(robot_section().get("effects") or {})


def robot_model() -> Any:
    """The bench robot's model: config/model.yaml with its plant off nominal by the `plant:`
    factors, its `effects` and its `discovered` terms (physics outside the vocabulary).
    """
    # deferred: the model loads scipy.signal (1.2-1.7 s); `flaair experiment --help` needs none
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model
    from flaair_model.term_entry import term_from_dict

    section = robot_section()
    model = with_effects(load_model(), robot_effects())
    factors = dict(section.get("plant") or {})
    model = replace(
        model,
        plant=replace(
            model.plant, **{k: getattr(model.plant, k) * float(f) for k, f in factors.items()}
        ),
    )
    terms = tuple(
        term_from_dict(t, f"robot.discovered[{i}]")
        for i, t in enumerate(section.get("discovered") or [])
    )
    return replace(model, discovered=terms)


def write_robot_model(path: Path) -> Path:
    """The bench robot's model file (`robot_model`)."""
    # deferred: the model loads scipy.signal (1.2-1.7 s); `flaair experiment --help` needs none
    from flaair_model.model_io import save_model

    save_model(robot_model(), path)
    return path
