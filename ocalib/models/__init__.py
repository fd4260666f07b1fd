"""Depth and pose networks for self-supervised ego-motion (see :class:`EgoMotionModel`)."""

from ocalib.models.depth import DepthNet, disp_to_depth
from ocalib.models.egomotion import MAX_DEPTH, MIN_DEPTH, SIZES, EgoMotionModel
from ocalib.models.io import DEFAULT_CHECKPOINT, load_model, save_model
from ocalib.models.pose import PoseNet, motion_to_pose

__all__ = [
    "DEFAULT_CHECKPOINT",
    "DepthNet",
    "EgoMotionModel",
    "MAX_DEPTH",
    "MIN_DEPTH",
    "PoseNet",
    "SIZES",
    "disp_to_depth",
    "load_model",
    "motion_to_pose",
    "save_model",
]
