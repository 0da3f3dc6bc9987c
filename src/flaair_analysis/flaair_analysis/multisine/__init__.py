"""Odd random-phase multisines (../shared/multisine.md), pure: the design, the line spectra,
the best linear approximation with its noise and nonlinear distortion, the class of each
channel, the model's distortion beside the measured one, and where a distortion points.

Modules (import them by name; this package imports none of them eagerly):
- `design`: the odd random-phase multisine design and each realization's drive;
- `spectra`: period and excited lines from the drive, transient periods, video grids, Y_mp(k);
- `nld`: BLA, noise and distortion (Pintelon and Schoukens' robust method), levels, class,
  the model's figures and the disagreements;
- `localise`: the reading of which channels show odd or even distortion;
- `analysis`: the whole analysis of a set of runs, with its refusals, and what the runs say of a
  model (`model_reading`);
- `spectrum_evidence`: the set's line spectra as evidence for the one fit
  (`flaair_analysis.evidence`): the model's spectra against the measured ones over the band.
"""

__all__ = ["analysis", "design", "localise", "nld", "spectra", "spectrum_evidence"]
