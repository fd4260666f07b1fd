"""The on-line rig estimator: the whole extrinsic of every camera, translation included, kept up to date as the
stream goes, in memory that does not grow with the sequence, and a change of any camera's mounting noticed.

Camera 0's metric trajectory (wheel odometry, GNSS, a stereo or visual-inertial system) is the rig's path: held as
given (as CamOdoCal holds the odometry) where it is exact (``metric_noise`` 0), or by default its positions are
priors of ``metric_noise`` metres and the images solve the rig's poses with the extrinsics (a real trajectory's
rotation, tenths of a degree off, would otherwise read as the cameras moving); what the images must give is each
camera's extrinsic. The local map (keyframes and points) is :mod:`ocalib.rigba.local_map`'s, each camera's state
(its phase, below, and its fused extrinsic) :mod:`ocalib.rigba.camera_state`'s. Every ``keyframe_step``-th frame,
:meth:`OnlineRigEstimator.update`:

1. (map) extracts every camera's features (:mod:`ocalib.rigba.features`) and matches them to the same camera's
   ``match_previous`` latest keyframes;
2. (map) resects every camera from its 2-D-3-D matches (COLMAP's absolute pose), keeping the matches that agree:
   with the rig's pose (camera 0's own resection where the poses are solved), each gives that keyframe's own
   measurement of the camera's extrinsic, with its information;
3. (observe) tests each measurement against the window's estimate for a change (:mod:`ocalib.rigba.change`);
4. (map, judge) continues the tracks the matches extend and triangulates new points, each camera where the window
   puts it, or where its own resection does while it disagrees with the window; a candidate change
   (``persistence`` tested keyframes in a row disagreeing) is judged by the window once it holds ``CONFIRM_SPAN``
   keyframes from the candidate's frame on (the camera held meanwhile, its new points where its own resections put
   it), adjusted with a second extrinsic for the camera from each of its disagreeing keyframes on
   (:func:`ocalib.rigba.window.split_statistic`), the change placed where that is largest (a stray keyframe may
   precede the move): a few resections misled by their points are not a move, nor is a step under
   ``min_change_deg`` and ``min_change_m``;
5. (adjust, judge) every ``adjust_every``-th keyframe, adjusts the points and every extrinsic over the last
   ``window`` keyframes (:mod:`ocalib.rigba.window`) and fuses the window's estimate into each camera's track. A
   camera *waits* (held, its track empty) at the start and after a change, until the window determines it: the
   1-sigma of its extrinsic, from the window's observations as if it were free (:mod:`ocalib.rigba.covariance`),
   under ``release_rotation_deg`` about every axis and under ``release_translation_m`` along the two
   best-determined directions (a car's height is never pinned by planar motion): released sooner, a window over a
   short stretch of motion throws the lever arm metres off; later, the stream is spent waiting. A waiting camera is
   solved apart from the rest (:func:`~ocalib.rigba.window.adjust_window`'s ``apart``): held at the head's
   rotation and no lever arm, its observations would bend the rig's poses and the other cameras' extrinsics; it is
   released where the window, trying it free against the rest, puts it, with its points (not while a candidate
   change of it awaits the split test: that camera stays in the joint adjustment, held at the estimate it had).

The estimator starts from the on-line head's rotations and zero lever arms; while a camera waits at the start, its
rotation follows the head's latest estimate (``update``'s ``rotations``); its translations are in metres.

Each camera's phase (:class:`~ocalib.rigba.camera_state.Phase`; camera 0 is the ``reference``):

============  ================================================  ================================================
phase         moved on by                                       where
============  ================================================  ================================================
waiting       the window determines it -> tracking              ``_adjust``, :meth:`CameraState.release`
tracking      a tested keyframe disagrees -> disagreeing;       ``_observe`` (:meth:`ExtrinsicTrack.observe`);
              the drift test -> waiting                         ``_adjust`` (:meth:`ExtrinsicTrack.drifted`,
                                                                :meth:`CameraState.restart`)
disagreeing   ``persistence`` in a row -> candidate;            ``_observe``
              one that agrees -> tracking
candidate     the split test, ``CONFIRM_SPAN`` keyframes on:    ``_judge``, ``_confirmed``
              confirmed -> waiting, dismissed -> tracking       (:meth:`CameraState.restart`)
============  ================================================  ================================================

The window holds a waiting or candidate camera; a suspect one (disagreeing or candidate) has its new points
triangulated where its own resection puts it. ``extrinsics`` is the window's working estimate of every camera,
each camera's track (:class:`~ocalib.rigba.change.ExtrinsicTrack`) the windows' estimates fused, reported in
:class:`RigState`.

Convention: poses camera-to-world (4, 4); ``extrinsics`` (C, 4, 4) ``T_cam0_camk`` (``p_cam0 = R p_camk + t``);
K (C, 3, 3) in ocalib's pixels (integer centres); images grayscale (H, W) uint8.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2 as chi2_distribution

from ocalib.calib.drivers.change import Change
from ocalib.data.distortion import Distortion
from ocalib.rigba.camera_state import CameraState
from ocalib.rigba.change import UNINFORMED, ExtrinsicTrack, determines, reaches, with_unobservable
from ocalib.rigba.local_map import LocalMap, Measured
from ocalib.rigba.options import DEFAULT_METRIC_NOISE
from ocalib.rigba.window import Keyframe, SplitTest, adjust_window, split_statistic

MIN_POINTS = 10  # 3-D points a window needs before it is adjusted
CONFIRM_FALSE_ALARM = 1e-12  # the split test's level, stricter: it runs where the data already chose a moment
MIN_KEYFRAMES = 5  # keyframes a window needs before it is adjusted (the points are triangulated from the first two)
CONFIRM_SPAN = 4  # keyframes from a candidate change's frame on before the window's split test judges it


@dataclass(frozen=True)
class OnlineRigOptions:
    """The on-line rig estimator's settings."""

    keyframe_step: int = 2  # every K-th frame is a keyframe
    window: int = 30  # keyframes adjusted together
    adjust_every: int = 2  # keyframes between two adjustments of the window (each adjustment is half the cost)
    match_previous: int = 3  # earlier keyframes each new one is matched to, per camera
    max_features: int = 1024  # SIFT keypoints an image
    # images wider are shrunk to this width for SIFT, keypoints scaled back: its cost grows with the pixels, and the
    # estimator's tests were validated on 416-px-wide renders (docs/benchmarks.md: KITTI's 1241 px at 416)
    sift_max_width: int | None = 416
    min_inliers: int = 15  # 2-D-3-D inliers for a keyframe to count as registered
    min_test_inliers: int = 30  # 2-D-3-D inliers for a keyframe to be tested for a change
    min_angle_deg: float = 1.0  # a new point's least triangulation angle
    false_alarm: float = 1e-8  # a keyframe's chance to look like a change, were the test's ratio chi-square
    persistence: int = 2  # keyframes in a row that must disagree before a change is declared
    # the trajectory's noise (m per axis): its positions are priors and the images solve the rig's poses; 0 or
    # None: held as given (an exact trajectory, e.g. a render's)
    metric_noise: float | None = DEFAULT_METRIC_NOISE
    # the least step the window's split test must find to confirm a change (rotation deg, or translation m): real
    # images hold what no model does (intrinsics, texture, moving things) and make smaller steps significant
    min_change_deg: float = 0.25
    min_change_m: float = 0.1
    # a waiting camera is released once the window's 1-sigma of it is under these (see the module)
    release_rotation_deg: float = 0.5
    release_translation_m: float = 0.1


@dataclass
class RigState:
    """The estimate after one keyframe: the fused ``extrinsics`` (C, 4, 4) in metres (a NaN translation for a camera
    still waiting since the start), their 1-sigma ``std`` (C, 6)
    (rotation rad, translation m; camera 0's axes; NaN where not yet known, inf where the data do not inform it), each
    camera's normalised change statistic ``chi2`` (C,), whether the
    keyframe ``registered`` (every camera resected from its matches), the ``changes`` (camera, change) it completed,
    the ``seconds`` it took, and each camera's ``phases`` (C,) after it (:class:`~ocalib.rigba.camera_state.Phase`'s
    labels: camera 0 ``reference``, the others ``waiting``, ``tracking``, ``disagreeing`` or ``candidate``)."""

    frame: int
    extrinsics: np.ndarray
    std: np.ndarray
    chi2: np.ndarray
    registered: bool
    changes: list[tuple[int, Change]]
    seconds: float
    phases: list[str]


class OnlineRigEstimator:
    """See the module. K (C, 3, 3), ``sizes`` (C,) of (height, width) and ``distortions`` (C,) (None: pinhole) are
    the cameras'; ``extrinsics`` (C, 4, 4) the start (their rotations are used, the lever arms start at zero)."""

    def __init__(
        self,
        K: np.ndarray,
        sizes: list[tuple[int, int]],
        extrinsics: np.ndarray,
        options: OnlineRigOptions = OnlineRigOptions(),
        distortions: list[Distortion | None] | None = None,
    ):
        self.K, self.sizes, self.options = np.asarray(K, np.float64), list(sizes), options
        self.extrinsics = np.array(extrinsics, dtype=np.float64)  # the window's working estimate
        self.extrinsics[:, :3, 3] = 0.0
        self.extrinsics[0] = np.eye(4)
        least = (options.min_change_deg, options.min_change_m)
        tracks = [ExtrinsicTrack(options.false_alarm, options.persistence, least) for _ in self.K]
        self.cameras = [CameraState.reference(tracks[0])] + [CameraState(k, t) for k, t in enumerate(tracks) if k]
        self.map = LocalMap(self.K, self.sizes, options, distortions or [None] * len(self.K))
        self.frames_seen = 0
        self.keyframes_unregistered = 0
        self.windows_solved = 0  # adjustments of the window that solved the rig's poses
        self.windows_without_priors = 0  # of those, the ones anchored at two keyframes instead (window.aligns)
        self.dismissed: list[tuple[int, int, SplitTest]] = []  # candidates the window did not confirm: camera, frame

    @property
    def candidates(self) -> dict[int, Change]:
        """Camera -> its candidate change awaiting the window's split test, in the order they were raised (one raised
        in the stream's last keyframes is never judged: the camera keeps the window's estimate, and OnlineRigStage
        reports it)."""
        raised = [(k, cam.candidate) for k, cam in enumerate(self.cameras) if cam.candidate is not None]
        return dict(sorted(raised, key=lambda kc: kc[1].detected))

    @property
    def keyframe_next(self) -> bool:
        """Whether the next frame :meth:`update` consumes is a keyframe: only then are its images used."""
        return self.frames_seen % self.options.keyframe_step == 0

    def update(
        self, frame: int, images: list[np.ndarray] | None, pose: np.ndarray, rotations: np.ndarray | None = None
    ) -> RigState | None:
        """Consume frame ``frame``: ``images`` one per camera (None will do where not :attr:`keyframe_next`),
        ``pose`` camera 0's metric camera-to-world pose (4, 4), or (C, 4, 4) the rig's pose when each camera captured
        its image (cameras without a shared trigger: the trajectory interpolated at each one's capture time);
        ``rotations`` (C - 1, 3, 3) the on-line head's latest rotations of cameras 1.., taken by those waiting since
        the start. Returns the state after a keyframe, None for the frames between."""
        self.frames_seen += 1
        if (self.frames_seen - 1) % self.options.keyframe_step:
            return None
        start = time.perf_counter()
        self._follow_head(rotations)
        kf = self.map.keyframe(frame, images, pose)  # map: extract
        measured = {}
        if self.map.keyframes:
            recent, matches = self.map.match(kf)  # map: match
            measured = self.map.resect(kf, recent, matches)  # map: resect
            self._observe(frame, measured)  # observe: the keyframes' test, before a suspect camera's new points
            self.map.triangulate(kf, recent, matches, self._poses(kf, measured), self.extrinsics)  # map: triangulate
        self.map.add(kf)
        changes = self._judge(frame)  # judge: the split test of the candidates due, on the last window's estimate
        adjust = (self.frames_seen - 1) // self.options.keyframe_step % self.options.adjust_every == 0
        if adjust and len(self.map.keyframes) >= MIN_KEYFRAMES and len(self.map.points) >= MIN_POINTS:
            changes += self._adjust(frame)  # adjust: the window; then release, and judge: the drift test
        registered = len(measured) == len(images)
        return self._state(frame, registered, changes, time.perf_counter() - start)

    def _follow_head(self, rotations: np.ndarray | None) -> None:
        """Turn each camera waiting since the start to the head's latest rotation (``rotations`` (C - 1, 3, 3))."""
        if rotations is None:
            return
        for k, cam in enumerate(self.cameras):
            if cam.follows_head and np.isfinite(rotations[k - 1]).all():
                self.extrinsics[k][:3, :3] = rotations[k - 1]

    def _observe(self, frame: int, measured: Measured) -> None:
        """Count the new keyframe's resections (``measured``: :meth:`LocalMap.resect`) and test each camera's
        measured extrinsic against the window's (:meth:`ExtrinsicTrack.observe`): a candidate change it completes
        becomes the camera's, unless one already awaits the split test."""
        self.keyframes_unregistered += len(measured) < len(self.cameras)
        for k, cam in enumerate(self.cameras):
            cam.tried += 1
            cam.registered += k in measured
        for k, (extrinsic, info) in measured.items():
            cam = self.cameras[k]
            reference = self.extrinsics[k], cam.window_covariance
            change = cam.track.observe(frame, extrinsic, info, reference) if k > 0 else None
            if change is not None and cam.candidate is None:
                cam.candidate = change

    def _poses(self, kf: Keyframe, measured: Measured) -> list[np.ndarray]:
        """Each camera's ``cam_from_world`` (4, 4) at the new keyframe: where the window puts it, or where its own
        resection does while it is suspect (:attr:`CameraState.suspect`: so that a knocked camera's new points are
        where it now looks, and the next keyframes measure the new mounting instead of the old one their points
        would give)."""
        return [
            np.linalg.inv(kf.poses[k] @ (measured[k][0] if k in measured and cam.suspect else E))
            for k, (cam, E) in enumerate(zip(self.cameras, self.extrinsics))
        ]

    def _adjust(self, frame: int) -> list[tuple[int, Change]]:
        """Adjust the window (the cameras held as :attr:`CameraState.held`, the waiting ones apart); release each
        waiting camera the window determines, where its try puts it; fuse each other one's estimate into its track,
        after the drift test, which restarts the camera where the window followed a move -> the changes the drift
        test found."""
        held = frozenset(k for k, cam in enumerate(self.cameras) if cam.held)
        apart = frozenset(k for k, cam in enumerate(self.cameras) if cam.waiting and cam.candidate is None)
        window = adjust_window(list(self.map.keyframes), self.map.points, self.extrinsics, self.K, self.sizes, held,
                               self.options.metric_noise, apart)  # fmt: skip
        self.windows_solved += window.priors_used is not None
        self.windows_without_priors += window.priors_used is False
        changes = []
        for k, u in enumerate(window.uncertainty, start=1):
            if u is None:
                continue
            cam = self.cameras[k]
            covariance = with_unobservable(u.covariance, u.unobservable)
            if cam.waiting and k in window.trials and determines(covariance, self.release_std):
                self.extrinsics[k], placed = window.trials[k]  # where the window, trying it free, puts it
                self.map.points.update(placed)
                cam.release(frame)
            elif k not in held:
                cam.window_covariance = covariance
                drift = cam.track.drifted(frame, self.extrinsics[k], cam.window_covariance)
                if drift is not None:
                    cam.restart(drift, self.extrinsics[k], self.map)
                    changes.append((k, drift))
                cam.track.fuse(self.extrinsics[k], cam.window_covariance)
        return changes

    @property
    def release_std(self) -> tuple[float, float]:
        """The 1-sigmas (rotation deg, translation m) under which the window determines a camera (see the module)."""
        return self.options.release_rotation_deg, self.options.release_translation_m

    def _judge(self, frame: int) -> list[tuple[int, Change]]:
        """The candidates judged at keyframe ``frame`` by the window's split test, once ``CONFIRM_SPAN``
        keyframes from the candidate's frame on are in the window (two keyframes misled by their matches, as on a
        repeated texture, decide less among four) -> the changes confirmed (noticed at ``frame``)."""
        changes = []
        for k, change in self.candidates.items():
            if sum(kf.frame >= change.frame for kf in self.map.keyframes) >= CONFIRM_SPAN:
                self.cameras[k].candidate = None
                confirmed = self._confirmed(k, change)
                if confirmed is not None:
                    changes.append((k, replace(confirmed, detected=frame)))
        return changes

    def _confirmed(self, k: int, change: Change) -> Change | None:
        """Whether the window confirms camera k's candidate ``change``: the window's split test at each of its
        disagreeing keyframes (a stray one may precede the move), the largest over its quantile at
        ``CONFIRM_FALSE_ALARM`` by a step of at least the least change. Confirmed, the change is placed at that
        keyframe (:meth:`ExtrinsicTrack.candidate_from`), and the camera restarts (:meth:`CameraState.restart`: from
        the disagreeing keyframes' mean measurement from there, with the lever arm it had, its observations from
        before the change dropped, waiting until the window determines it); dismissed, the track forgets the
        candidate. -> the change confirmed, or None."""
        cam = self.cameras[k]
        frames = [f for f, _, _ in cam.track.disagreed] or [change.frame]
        split, frame = max(
            ((self._split(k, f), f) for f in frames), key=lambda sf: np.nan_to_num(sf[0].statistic, nan=-np.inf)
        )
        level = chi2_distribution.ppf(1 - CONFIRM_FALSE_ALARM, 6)
        if not (split.statistic > level and reaches(split.step, cam.track.min_change)):  # NaN: too little
            cam.track.dismiss()
            self.dismissed.append((k, change.detected, split))
            return None
        if cam.track.disagreed:
            change = cam.track.candidate_from(frame, change.detected)
        cam.restart(change, self.extrinsics[k], self.map)
        return change

    def _split(self, k: int, frame: int) -> SplitTest:
        """The window's split test of camera k moving at keyframe ``frame`` (:func:`split_statistic`)."""
        keyframes, noise = list(self.map.keyframes), self.options.metric_noise
        return split_statistic(keyframes, self.map.points, self.extrinsics, self.K, self.sizes, k, frame, noise)

    def _state(self, frame: int, registered: bool, changes, seconds: float) -> RigState:
        C = len(self.K)
        extrinsics = np.tile(np.eye(4), (C, 1, 1))
        std = np.full((C, 6), np.nan)
        std[0] = 0.0
        for k in range(1, C):
            track = self.cameras[k].track
            if track.extrinsic is not None:
                extrinsics[k] = track.extrinsic
                variance = np.clip(np.diag(track.covariance), 0, None)
                std[k] = np.where(variance < UNINFORMED / 10, np.sqrt(variance), np.inf)
            else:  # waiting since the start: the head's rotation, no lever arm yet
                extrinsics[k] = self.extrinsics[k]
                extrinsics[k, :3, 3] = np.nan
        chi2 = np.array([cam.track.chi2 for cam in self.cameras])
        phases = [cam.phase.label for cam in self.cameras]
        return RigState(frame, extrinsics, std, chi2, registered, changes, seconds, phases)
