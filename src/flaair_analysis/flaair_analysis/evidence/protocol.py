"""What a measurement tells the fit: the `Evidence` protocol. Pure.

A run set, a frequency-response table (and a multisine spectrum) is evidence about a model. Given
a batch of models and the evidence's own nuisance parameters (a run's initial state; a table has
none) it returns residuals in units of its own noise, so that the sum of squares over every piece
of evidence is one chi-square and one least-squares fit (`fit_evidence`) serves any mix of them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from flaair_model.model import Model

__all__ = ["Evidence", "EvidenceSet", "Split"]


@runtime_checkable
class Evidence(Protocol):
    """Residuals of a batch of models against one measured data set, in units of its noise.

    Attributes
    ----------
    name : what the evidence is ("runs", "table"), as the fit's reports name it.
    sites : the channels or columns it sees (a residual row of each is in the output).
    n_nuisance : fitted parameters of its own (each run's angle and rate; 0 for a table).
    """

    name: str
    sites: tuple[str, ...]
    n_nuisance: int

    def nuisance_start(self) -> np.ndarray:
        """(n_nuisance,) start of its own parameters (fit space)."""
        ...

    def nuisance_steps(self) -> np.ndarray:
        """(n_nuisance,) forward-difference steps of its own parameters (fit space)."""
        ...

    def residuals(self, models: Sequence[Model], nuisance: np.ndarray) -> np.ndarray:
        """(len(models), n) residual rows in units of the noise, at the nuisance `nuisance`."""
        ...

    def linearised(
        self, models: Sequence[Model], nuisance: np.ndarray, h: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The rows of `models` at `nuisance` ((len(models), n)) and the Jacobian of the first
        model's row in the nuisance parameters ((n, n_nuisance), forward differences of `h`),
        from one batch where the evidence can.
        """
        ...

    def heldout(self) -> tuple[Split, ...]:
        """Its held-out splits: each part judged by a model fitted on the rest."""
        ...

    def site_index(self) -> dict[str, np.ndarray]:
        """Per site, the positions of its residuals in a residual row."""
        ...


@dataclass(frozen=True)
class Split:
    """One held-out split of a piece of evidence.

    Attributes
    ----------
    name : the part judged (a run, a run's half, a table's drive level).
    fit : the evidence a model is fitted on (the rest).
    judged : the evidence the fitted model is judged on (the part).
    where : where the part lies in the whole, in the kind's own terms (a run's `Fold`, a
        table's boolean mask of its points).
    """

    name: str
    fit: Evidence
    judged: Evidence
    where: Any


@runtime_checkable
class EvidenceSet(Protocol):
    """A measured set beside the runs in the joint identification (a table, a multisine set's
    spectra, any new kind): what each side's stage is fitted on, and how the fitted model agrees
    with the whole set.

    Attributes
    ----------
    name : the set's name in the fit's agreements and reports ("table", "spectra").
    """

    name: str

    def stage_piece(self, side: str, channel: str) -> Evidence | None:
        """The evidence the `side` ("stroke", "pitch") stage is fitted on, whose truth channel is
        `channel` (None: the set does not see that side).
        """
        ...

    def set_scores(self, model: Model) -> tuple[dict[str, float], dict[str, float], int, float]:
        """`model` against the set, where it is fitted: per site the residual RMS over the noise
        and the NRMSE, the residual count, the chi-square.
        """
        ...
