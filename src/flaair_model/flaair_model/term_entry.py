"""A discovered term as an entry of a model file (`discovered:`) or of discrepancy.json.

One shape both ways: what `term_to_dict` writes and what discrepancy.json's `discovered` entries
say, `term_from_dict` reads (parameters as numbers or {value, stderr}; the discovery's account,
`REPORT_KEYS`, is shown to the reader and not read back).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from flaair_model.terms import DiscoveredTerm
from flaair_model.validation import ModelError, coerce_number

__all__ = ["REPORT_KEYS", "term_from_dict", "term_to_dict"]


def term_to_dict(term: DiscoveredTerm) -> dict[str, Any]:
    """The model-file entry: kind, acts_on, expression (for the reader), parameters."""
    return {
        "kind": term.kind,
        "acts_on": term.acts_on,
        "expression": term.expression,
        "parameters": {"coefficient": term.coefficient, **dict(term.shape)},
    }


# What a discrepancy.json `discovered` entry says beyond the model-file entry: the discovery's
# account of the term, shown to the reader and not read back (a model file may carry it).
REPORT_KEYS: tuple[str, ...] = (
    "composed",
    "feature",
    "words",
    "examples",
    "judged_on",
    "gap_before",
    "gap_after",
    "candidates_beaten",
    "uncertainty",
    "evidence",
)


def _parameter(where: str, raw: Any) -> Any:
    """A parameter's value: a number, or discrepancy.json's {value, stderr}."""
    if isinstance(raw, Mapping):
        if "value" not in raw or set(raw) - {"value", "stderr"}:
            raise ModelError(f"{where} must be a number or a mapping {{value, stderr}}")
        raw = raw["value"]
    return coerce_number(raw)


def term_from_dict(raw: Any, where: str = "discovered") -> DiscoveredTerm:
    """A `DiscoveredTerm` from its model-file entry or its discrepancy.json entry.

    `expression` and the discovery's account (`REPORT_KEYS`) are derived or reported, not
    read; each parameter is a number or a {value, stderr} mapping (its value is taken).
    """
    if not isinstance(raw, Mapping):
        raise ModelError(
            f"{where} must be a mapping with kind, acts_on and parameters, got {type(raw).__name__}"
        )
    known = {"kind", "acts_on", "expression", "parameters", *REPORT_KEYS}
    unknown = sorted(set(map(str, raw)) - known)
    if unknown:
        raise ModelError(f"{where}: unknown key(s) {', '.join(unknown)}")
    missing = [k for k in ("kind", "acts_on", "parameters") if k not in raw]
    if missing:
        raise ModelError(f"{where}: missing key(s) {', '.join(missing)}")
    params = raw["parameters"]
    if not isinstance(params, Mapping) or "coefficient" not in params:
        raise ModelError(f"{where}.parameters must be a mapping with a coefficient")
    values = {str(k): _parameter(f"{where}.parameters.{k}", v) for k, v in params.items()}
    coefficient = values.pop("coefficient")
    return DiscoveredTerm(str(raw["kind"]), str(raw["acts_on"]), coefficient, tuple(values.items()))
