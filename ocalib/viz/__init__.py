"""Plots of calibration results (matplotlib, imported on use)."""
