"""The rig bundle adjustment's settings, light to import (no COLMAP): features and matching, the mapper, keyframes.

``MAPPERS`` is the one list of COLMAP mappers the stage offers; the CLI's choices read it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

# global: COLMAP's GLOMAP (rotation averaging, global positioning, bundle adjustment), the default: faster than
# incremental at equal accuracy (docs/results-rigba.md). incremental: frame by frame, bundle adjustment after each few.
MAPPERS = ("global", "incremental")
# metres per axis the on-line rig estimator takes a metric trajectory to be off by where its user does not say
DEFAULT_METRIC_NOISE = 0.05


@dataclass(frozen=True)
class FeatureOptions:
    """Features and matching: SIFT keypoints per image, each frame matched to the next ``overlap`` frames."""

    max_features: int = 2048
    peak_threshold: float = 0.002  # SIFT's contrast threshold (COLMAP's default 0.0067 finds ~20 % fewer keypoints)
    overlap: int = 5
    cross_camera: bool = False  # also match camera j's images to camera k's (cameras that share a view, e.g. stereo)
    threads: int = 1  # 1: the same images give the same matches (on more, the mapper's result moves from run to run)


@dataclass(frozen=True)
class MapperOptions:
    """The mapper's settings that matter here (COLMAP's defaults otherwise)."""

    kind: str = "global"  # one of MAPPERS
    refine_intrinsics: bool = False  # hold K as given (the default); True refines focal lengths and principal points
    threads: int = 1  # 1: the same input gives the same result bit for bit (on more, it moves from run to run)
    seed: int = 0  # COLMAP's RANSAC and initial choices
    metric_noise: float | None = None  # metres per axis: a metric trajectory's positions as priors so weighed in a
    # last adjustment; 0: its poses held fixed there (None: a Sim(3) fit to it only)


@dataclass(frozen=True)
class BundleOptions:
    """The stage's settings: features and matching, the mapper, and the frames used (every ``keyframe_step``-th)."""

    features: FeatureOptions = field(default_factory=FeatureOptions)
    mapper: MapperOptions = field(default_factory=MapperOptions)
    keyframe_step: int = 2
