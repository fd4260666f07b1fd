"""Calibrating a rig from its images: the on-line calibration net and the runner behind ``ocalib calibrate``."""

from ocalib.calibnet.net import OnlineCalibrationNet

__all__ = ["OnlineCalibrationNet"]
