"""Ego-motion front ends that turn each camera's images into its trajectory for the calibration.

:class:`OpenCVOdometry` is the classical monocular VO (KLT tracks, essential matrix, scale propagated
along the tracks); :func:`run_opencv_vo` runs it over a whole sequence. :func:`align_motion` refines a
network's frame-to-frame motion by direct photometric alignment on the network's depth.
"""

from ocalib.frontend.align import align_motion
from ocalib.frontend.opencv_vo import OpenCVOdometry, VOStatus, run_opencv_vo

__all__ = ["OpenCVOdometry", "VOStatus", "align_motion", "run_opencv_vo"]
