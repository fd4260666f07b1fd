"""Evaluating against the truth: depth and pose metrics, Sim(3) alignment, a calibration's errors, the prediction loop,
plots.

Names are imported lazily so that the metrics stay free of torch and matplotlib until used.
"""

from importlib import import_module

_EXPORTS = {
    "umeyama": "alignment",
    "align_poses": "alignment",
    "align_trajectory": "alignment",
    "depth_errors": "depth_metrics",
    "mean_depth_errors": "depth_metrics",
    "pose_metrics": "pose_metrics",
    "snippet_ate": "pose_metrics",
    "frame_errors": "pose_metrics",
    "rpe": "pose_metrics",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(f"ocalib.eval.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'ocalib.eval' has no attribute {name!r}")
