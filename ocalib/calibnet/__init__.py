"""Calibrating a rig from its images: the on-line calibration net and the runner behind ``ocalib calibrate``.
:class:`OnlineCalibrationNet` is loaded on first use, so that :mod:`ocalib.calibnet.sequence` (the sequence opened
and checked) loads no torch."""

from importlib import import_module

__all__ = ["OnlineCalibrationNet"]


def __getattr__(name: str):
    if name == "OnlineCalibrationNet":
        return import_module("ocalib.calibnet.net").OnlineCalibrationNet
    raise AttributeError(f"module 'ocalib.calibnet' has no attribute {name!r}")
