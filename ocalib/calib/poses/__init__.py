"""``ocalib calibrate-poses``: trajectory files in, the calibration and its report (JSON, trace, warnings,
summary) out."""
