"""FLAAIR sensor front end: PVDF charge model, inverse sensor model, calibration."""
