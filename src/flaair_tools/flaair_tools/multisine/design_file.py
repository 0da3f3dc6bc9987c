"""multisine.yaml: a design written and read back (../shared/multisine.md, section 1)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml

from flaair_analysis.multisine.design import DesignError, MultisineDesign
from flaair_model.config import ConfigError, load_yaml

__all__ = ["DESIGN_FILE", "design_doc", "dump_design", "read_design", "realization_file"]

DESIGN_FILE = "multisine.yaml"


def realization_file(m: int) -> str:
    """The CSV of realization m (0-based): realization_<m+1>.csv."""
    return f"realization_{m + 1}.csv"


def design_doc(d: MultisineDesign) -> dict[str, Any]:
    """The design as multisine.yaml holds it."""
    return {
        "fs_hz": d.fs_hz,
        "period_samples": d.period_samples,
        "base_frequency_hz": d.base_frequency_hz,
        "band_hz": list(d.band_hz),
        "lines_per_group": d.lines_per_group,
        "excited_lines": list(d.excited_lines),
        "odd_detection_lines": list(d.odd_detection_lines),
        "rms_v": d.rms_v,
        "amplitude_v": d.amplitude_v,
        "transient_periods": d.transient_periods,
        "periods": d.periods,
        "realizations": d.realizations,
        "seed": d.seed,
        "phases_rad": [[float(p) for p in row] for row in d.phases_rad],
        "files": [realization_file(m) for m in range(d.realizations)],
    }


def dump_design(d: MultisineDesign) -> str:
    """multisine.yaml's text (lists of numbers on one line each)."""
    return yaml.safe_dump(design_doc(d), sort_keys=False, default_flow_style=None, width=100)


def _int_list(doc: dict[str, Any], key: str, where: Path) -> tuple[int, ...]:
    values = doc.get(key)
    if not isinstance(values, list) or not all(
        isinstance(v, int) and not isinstance(v, bool) for v in values
    ):
        raise DesignError(f"{where}: {key} must be a list of whole numbers")
    return tuple(values)


def _number(doc: dict[str, Any], key: str, where: Path) -> float:
    value = doc.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise DesignError(f"{where}: {key} must be a finite number, got {value!r}")
    return float(value)


def read_design(path: Path) -> MultisineDesign:
    """A multisine.yaml read and checked; DesignError names the file and the key."""
    try:
        doc = load_yaml(path)
    except (ConfigError, OSError) as exc:
        raise DesignError(f"--design {path}: {exc}") from None
    if not isinstance(doc, dict):
        raise DesignError(f"--design {path}: not a multisine design (a mapping of keys)")
    n = _number(doc, "period_samples", path)
    phases = doc.get("phases_rad")
    excited = _int_list(doc, "excited_lines", path)
    if not isinstance(phases, list) or not all(
        isinstance(row, list) and len(row) == len(excited) for row in phases
    ):
        raise DesignError(f"{path}: phases_rad must hold one list per realization, one per line")
    ints = {
        k: int(_number(doc, k, path))
        for k in ("lines_per_group", "transient_periods", "periods", "realizations", "seed")
    }
    if n != round(n) or n < 4 or ints["transient_periods"] < 0:
        raise DesignError(f"{path}: period_samples must be a whole number >= 4")
    if not excited or max(excited) >= n / 2 or min(excited) < 1:
        raise DesignError(f"{path}: excited_lines must lie in [1, period_samples / 2)")
    band = doc.get("band_hz")
    if not (isinstance(band, list) and len(band) == 2):
        raise DesignError(f"{path}: band_hz must be [F1, F2]")
    return MultisineDesign(
        fs_hz=_number(doc, "fs_hz", path),
        period_samples=int(n),
        band_hz=(float(band[0]), float(band[1])),
        lines_per_group=ints["lines_per_group"],
        excited_lines=excited,
        odd_detection_lines=_int_list(doc, "odd_detection_lines", path),
        rms_v=_number(doc, "rms_v", path),
        amplitude_v=_number(doc, "amplitude_v", path),
        transient_periods=ints["transient_periods"],
        periods=ints["periods"],
        realizations=ints["realizations"],
        seed=ints["seed"],
        phases_rad=tuple(tuple(float(p) for p in row) for row in phases),
    )
