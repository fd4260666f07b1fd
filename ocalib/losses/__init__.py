"""Self-supervised depth and ego-motion losses built on kornia (warp, photometric, smoothness, consistency, gauge,
motion distance)."""

from ocalib.losses.consistency import depth_inconsistency
from ocalib.losses.gauge import scale_gauge
from ocalib.losses.motion import motion_distance
from ocalib.losses.photometric import photometric_error, ssim_error
from ocalib.losses.selfsup import LossOutput, SelfSupervisedLoss, min_reprojection, self_supervised_loss
from ocalib.losses.smoothness import edge_aware_smoothness
from ocalib.losses.warp import Warp, inverse_warp

__all__ = [
    "LossOutput",
    "SelfSupervisedLoss",
    "Warp",
    "depth_inconsistency",
    "edge_aware_smoothness",
    "inverse_warp",
    "min_reprojection",
    "motion_distance",
    "photometric_error",
    "scale_gauge",
    "self_supervised_loss",
    "ssim_error",
]
