"""One camera's state in the on-line rig estimator (:mod:`ocalib.rigba.online`): its :class:`Phase`, its fused
extrinsic (:class:`~ocalib.rigba.change.ExtrinsicTrack`), its release and its resection counts, and the one way it
restarts after a change (:meth:`CameraState.restart`), whether the window's split test confirmed the keyframes'
candidate or the drift test caught the window following the move.

Convention: extrinsics ``T_cam0_camk`` (4, 4) (``p_cam0 = R p_camk + t``), translations in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np

from ocalib.calib.drivers.change import Change
from ocalib.rigba.change import UNINFORMED, ExtrinsicTrack, determines

if TYPE_CHECKING:
    from ocalib.rigba.local_map import LocalMap


class Phase(Enum):
    """Where a camera stands; the value is its code in the trace's ``rig_phase`` column."""

    REFERENCE = 0  # camera 0: the rig's frame, never estimated
    WAITING = 1  # held until the window determines it (at the start its rotation follows the head's)
    TRACKING = 2  # released: the window moves it and its track fuses the window's estimates
    DISAGREEING = 3  # its last tested keyframes disagree with the window, short of a candidate change
    CANDIDATE = 4  # a candidate change awaits the window's split test; the window holds the camera

    @property
    def label(self) -> str:
        return self.name.lower()


@dataclass
class CameraState:
    """Camera ``index``'s state: its ``track`` (the fused extrinsic and the keyframes' change test); ``waiting``
    (held until the window determines it) and ``follows_head`` (waiting since the start: its rotation follows the
    on-line head's); the ``candidate`` change awaiting the window's split test (None: none); the keyframe it was
    last ``released_at``; and since then (or the start) the keyframes it was ``tried`` (resected) at, of which
    ``registered`` those it registered at; the ``window_covariance`` (6, 6) of the window's last estimate of it
    (rotation rad, translation m; uninformed before one)."""

    index: int
    track: ExtrinsicTrack
    waiting: bool = True
    follows_head: bool = True
    candidate: Change | None = None
    released_at: int | None = None
    tried: int = 0
    registered: int = 0
    window_covariance: np.ndarray = field(default_factory=lambda: np.eye(6) * UNINFORMED)

    @classmethod
    def reference(cls, track: ExtrinsicTrack) -> CameraState:
        """Camera 0's: never held, never tested."""
        return cls(0, track, waiting=False, follows_head=False)

    @property
    def phase(self) -> Phase:
        """The camera's :class:`Phase` (a candidate before waiting: one raised while the camera waits after a
        change is judged as any other; waiting before disagreeing: the window holds it either way)."""
        if self.index == 0:
            return Phase.REFERENCE
        if self.candidate is not None:
            return Phase.CANDIDATE
        if self.waiting:
            return Phase.WAITING
        return Phase.DISAGREEING if self.track.disagrees else Phase.TRACKING

    @property
    def held(self) -> bool:
        """Whether the window holds the camera: it waits, or a candidate change of it awaits judgement."""
        return self.waiting or self.candidate is not None

    @property
    def suspect(self) -> bool:
        """Whether its keyframes disagree with the window, or a candidate change of it awaits judgement: its new
        points are then triangulated where its own resection puts it."""
        return self.track.disagrees or self.candidate is not None

    def determined(self, release: tuple[float, float]) -> bool:
        """Whether its fused extrinsic is determined: released, or waiting after the drift test restarted it from the
        window estimate that found the move, whose covariance is under ``release`` (the 1-sigmas, rotation deg and
        translation m: :func:`~ocalib.rigba.change.determines`)."""
        covariance = self.track.covariance
        return not self.waiting or (covariance is not None and determines(covariance, release))

    def release(self, frame: int) -> None:
        """The window determines the camera at keyframe ``frame``: the next window moves it; its counts restart."""
        self.waiting = self.follows_head = False
        self.released_at, self.tried, self.registered = frame, 0, 0

    def restart(self, change: Change, working: np.ndarray, local_map: LocalMap) -> None:
        """The camera moved (``change``, its track's ``candidate`` the new extrinsic): the track records it and
        restarts, uninformed, from the candidate's rotation with the lever arm of the window's ``working``
        extrinsic (4, 4), which takes the same (a knock turns a camera more than it moves it; where the candidate is
        the window's own estimate, as the drift test's is, both are unchanged); ``local_map`` drops its
        observations from before ``change.frame``; the camera then waits, its rotation no longer following the
        head, until the window determines it."""
        lever_arm = working[:3, 3].copy()
        self.track.accept(change)
        working[:3, :3] = self.track.extrinsic[:3, :3]
        working[:3, 3] = self.track.extrinsic[:3, 3] = lever_arm
        local_map.forget(self.index, change.frame)
        self.waiting, self.follows_head = True, False
