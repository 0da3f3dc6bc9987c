"""The one rule that says whether a discrepancy outcome is right: exactly right, nothing missing
and nothing extra.

An outcome is right iff
- its status is the expected one,
- the vocabulary effects it names equal the truth's exactly, and
- the terms it discovers equal the truth's exactly, by site and form (`kind@acts_on`).

Secondary figures (the right form found among others, coefficient errors) are reported beside
it, never in its place. The benchmarks, the tests and the hidden-effect case scoring all call
`score_exact`; runs, tables and the joint mode are scored by it alike.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["ExactScore", "score_exact", "term_label"]


def term_label(kind: str, acts_on: str) -> str:
    """A discovered term's identity for scoring: its form and its site, 'kind@acts_on'."""
    return f"{kind}@{acts_on}"


@dataclass(frozen=True)
class ExactScore:
    """An outcome against the truth.

    Attributes
    ----------
    status, expected_status : reported and true status.
    missing_names, extra_names : vocabulary effects the truth has and the outcome does not, and
        the reverse (sorted).
    missing_terms, extra_terms : the same for discovered terms ('kind@acts_on', sorted).
    """

    status: str
    expected_status: str
    missing_names: tuple[str, ...] = ()
    extra_names: tuple[str, ...] = ()
    missing_terms: tuple[str, ...] = ()
    extra_terms: tuple[str, ...] = ()

    @property
    def status_right(self) -> bool:
        """Whether the status is the expected one."""
        return self.status == self.expected_status

    @property
    def names_right(self) -> bool:
        """Whether the named effects equal the truth's."""
        return not (self.missing_names or self.extra_names)

    @property
    def terms_right(self) -> bool:
        """Whether the discovered terms equal the truth's."""
        return not (self.missing_terms or self.extra_terms)

    @property
    def right(self) -> bool:
        """Status, named set and discovered set all equal the truth's."""
        return self.status_right and self.names_right and self.terms_right

    def problems(self) -> tuple[str, ...]:
        """Why the outcome is not right, one line each (empty when right)."""
        lines = []
        if not self.status_right:
            lines.append(f"status {self.status}, expected {self.expected_status}")
        for what, items in (
            ("effect missing", self.missing_names),
            ("effect named the truth lacks", self.extra_names),
            ("term missing", self.missing_terms),
            ("term discovered the truth lacks", self.extra_terms),
        ):
            lines += [f"{what}: {item}" for item in items]
        return tuple(lines)


def score_exact(
    *,
    status: str,
    names: Iterable[str],
    terms: Iterable[str],
    expected_status: str,
    expected_names: Iterable[str],
    expected_terms: Iterable[str],
) -> ExactScore:
    """Score one outcome exactly against its truth.

    Parameters
    ----------
    status, names, terms : the outcome: its status, the vocabulary effects it names, the terms it
        discovered (`term_label`).
    expected_status, expected_names, expected_terms : the truth's.
    """
    got_n, want_n = set(names), set(expected_names)
    got_t, want_t = set(terms), set(expected_terms)
    return ExactScore(
        status=status,
        expected_status=expected_status,
        missing_names=tuple(sorted(want_n - got_n)),
        extra_names=tuple(sorted(got_n - want_n)),
        missing_terms=tuple(sorted(want_t - got_t)),
        extra_terms=tuple(sorted(got_t - want_t)),
    )
