"""The on-line rig estimator: the whole extrinsic of every camera, translation included, kept up to date as the
stream goes, in memory that does not grow with the sequence, and a change of any camera's mounting noticed.

Camera 0's metric trajectory (wheel odometry, GNSS, a stereo or visual-inertial system) is the rig's path: held as
given (as CamOdoCal holds the odometry) where it is exact (``metric_noise`` 0), or by default its positions are
priors of ``metric_noise`` metres and the images solve the rig's poses with the extrinsics (a real trajectory's
rotation, tenths of a degree off, would otherwise read as the cameras moving); what the images must give is each
camera's extrinsic. Every ``keyframe_step``-th frame, :meth:`OnlineRigEstimator.update`:

1. extracts every camera's features (:mod:`ocalib.rigba.features`) and matches them to the same camera's
   ``match_previous`` latest keyframes;
2. resects every camera from its 2-D-3-D matches (COLMAP's absolute pose), keeping the matches that agree: with the
   rig's pose (camera 0's own resection where the poses are solved), each gives that keyframe's own measurement of
   the camera's extrinsic, with its information;
3. tests each measurement against the window's estimate for a change (:mod:`ocalib.rigba.change`);
4. continues the tracks the matches extend and triangulates new points, each camera where the window puts it, or
   where its own resection does while it disagrees with the window; a candidate change (``persistence``
   keyframes in a row disagreeing) is judged by the window once it holds ``CONFIRM_SPAN`` keyframes from the
   candidate's frame on (the camera held meanwhile, its new points where its own resections put it), adjusted
   with a second extrinsic for the camera from the candidate's frame, or one of the ``SPLIT_SEARCH`` keyframes
   before it (:func:`ocalib.rigba.window.split_statistic`): a few resections misled by their points are not a
   move, nor is a step under ``min_change_deg`` and ``min_change_m``;
5. every ``adjust_every``-th keyframe, adjusts the points and every extrinsic over the last ``window`` keyframes
   (:mod:`ocalib.rigba.window`) and fuses the window's estimate into each camera's track. A camera *waits* (held,
   its track empty) at the start and after a change, until the window determines it: the 1-sigma of its
   extrinsic, from the window's observations as if it were free (:mod:`ocalib.rigba.covariance`), under
   ``release_rotation_deg`` about every axis and under ``release_translation_m`` along the two best-determined
   directions (a car's height is never pinned by planar motion): released sooner, a window over a short stretch of
   motion throws the lever arm metres off; later, the stream is spent waiting.

The estimator starts from the on-line head's rotations and zero lever arms; while a camera waits at the start, its
rotation follows the head's latest estimate (``update``'s ``rotations``); its translations are in metres.

Convention: poses camera-to-world (4, 4); ``extrinsics`` (C, 4, 4) ``T_cam0_camk`` (``p_cam0 = R p_camk + t``);
K (C, 3, 3) in ocalib's pixels (integer centres); images grayscale (H, W) uint8.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, replace

import numpy as np
import pycolmap
from scipy.stats import chi2 as chi2_distribution

from ocalib.calib.drivers.change import Change
from ocalib.data.distortion import Distortion, undistort_pixels
from ocalib.rigba.change import (
    UNINFORMED,
    ExtrinsicTrack,
    information,
    reaches,
    relative_information,
    with_unobservable,
)
from ocalib.rigba.colmap import pinhole_params, to_matrix
from ocalib.rigba.features import Features, SiftExtractor, match_features
from ocalib.rigba.options import DEFAULT_METRIC_NOISE
from ocalib.rigba.window import MAX_ERROR_PX, Keyframe, SplitTest, adjust_window, shares_pose, split_statistic

MIN_POINTS = 10  # 3-D points a window needs before it is adjusted
CONFIRM_FALSE_ALARM = 1e-12  # the split test's level, stricter: it runs where the data already chose a moment
MIN_KEYFRAMES = 5  # keyframes a window needs before it is adjusted (the points are triangulated from the first two)
CONFIRM_SPAN = 4  # keyframes from a candidate change's frame on before the window's split test judges it
SPLIT_SEARCH = 3  # keyframes before a candidate's at which the split test also looks for the move


@dataclass(frozen=True)
class OnlineRigOptions:
    """The on-line rig estimator's settings."""

    keyframe_step: int = 2  # every K-th frame is a keyframe
    window: int = 30  # keyframes adjusted together
    adjust_every: int = 2  # keyframes between two adjustments of the window (each adjustment is half the cost)
    match_previous: int = 3  # earlier keyframes each new one is matched to, per camera
    max_features: int = 1024  # SIFT keypoints an image
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
    and the ``seconds`` it took."""

    frame: int
    extrinsics: np.ndarray
    std: np.ndarray
    chi2: np.ndarray
    registered: bool
    changes: list[tuple[int, Change]]
    seconds: float


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
        self.distortions = distortions or [None] * len(self.K)
        self.extrinsics = np.array(extrinsics, dtype=np.float64)
        self.extrinsics[:, :3, 3] = 0.0
        self.extrinsics[0] = np.eye(4)
        C = len(self.K)
        overlap = options.window / options.adjust_every  # windows a keyframe is adjusted in
        least = (options.min_change_deg, options.min_change_m)
        self.tracks = [ExtrinsicTrack(overlap, options.false_alarm, options.persistence, least) for _ in range(C)]
        self.window_covariance = np.tile(np.eye(6) * UNINFORMED, (C, 1, 1))  # of the window's last extrinsics
        self.keyframes: deque[Keyframe] = deque()
        self.points: dict[int, np.ndarray] = {}
        self._next_point = 0
        self._extract = SiftExtractor(options.max_features)
        self._cameras = [
            pycolmap.Camera(model="PINHOLE", width=w, height=h, params=pinhole_params(k), camera_id=i + 1)
            for i, (k, (h, w)) in enumerate(zip(self.K, self.sizes))
        ]
        self.frames_seen = 0
        self.keyframes_unregistered = 0
        self.dismissed: list[tuple[int, int, SplitTest]] = []  # candidates the window did not confirm: camera, frame
        # per camera, a candidate change awaiting CONFIRM_SPAN keyframes (one raised in the stream's last keyframes
        # is never judged: the camera keeps the window's estimate, and OnlineRigStage reports it)
        self.pending: dict[int, Change] = {}
        # per waiting camera (see the module), whether its rotation follows the head's (at the start, not after a change)
        self.waiting: dict[int, bool] = {k: True for k in range(1, C)}
        self.released: dict[int, int] = {}  # camera -> the keyframe it was last released at
        self.tried = np.zeros(C, int)  # per camera, the keyframes it was resected at since its release (or the start)
        self.resected = np.zeros(C, int)  # of which those it registered at

    def update(
        self, frame: int, images: list[np.ndarray], pose: np.ndarray, rotations: np.ndarray | None = None
    ) -> RigState | None:
        """Consume frame ``frame``: ``images`` one per camera, ``pose`` camera 0's metric camera-to-world pose (4, 4),
        or (C, 4, 4) the rig's pose when each camera captured its image (cameras without a shared trigger: the
        trajectory interpolated at each one's capture time); ``rotations`` (C - 1, 3, 3) the on-line head's latest
        rotations of cameras 1.., taken by those waiting since the start. Returns the state after a keyframe, None
        for the frames between."""
        self.frames_seen += 1
        if (self.frames_seen - 1) % self.options.keyframe_step:
            return None
        start = time.perf_counter()
        if rotations is not None:
            for k, follows in self.waiting.items():
                if follows and np.isfinite(rotations[k - 1]).all():
                    self.extrinsics[k][:3, :3] = rotations[k - 1]
        features = [self._features(image, k) for k, image in enumerate(images)]
        poses = np.broadcast_to(np.asarray(pose, np.float64), (len(images), 4, 4)).copy()
        kf = Keyframe(frame, self._working(poses), features, [np.full(len(f), -1) for f in features], poses[0].copy())
        measured = {}
        if self.keyframes:
            recent = list(self.keyframes)[-self.options.match_previous :]
            matches = [[match_features(f.descriptors, p.features[k].descriptors) for p in recent] for k, f in
                       enumerate(features)]  # fmt: skip
            measured = self._resect(kf, recent, matches)
            self.keyframes_unregistered += len(measured) < len(features)
            self.tried += 1
            self.resected[list(measured)] += 1
            candidates = self._candidates(frame, measured)
            self._triangulate(kf, recent, matches, self._poses(kf, measured))
        else:
            candidates = []
        self.keyframes.append(kf)
        self._evict()
        self.pending.update((k, self.pending.get(k, change)) for k, change in candidates)
        changes = self._judged(frame)
        adjust = (self.frames_seen - 1) // self.options.keyframe_step % self.options.adjust_every == 0
        if adjust and len(self.keyframes) >= MIN_KEYFRAMES and len(self.points) >= MIN_POINTS:
            held = frozenset(self.waiting) | frozenset(self.pending)  # waiting or suspect: the window does not move it
            window = adjust_window(list(self.keyframes), self.points, self.extrinsics, self.K, self.sizes, held,
                                   self.options.metric_noise)  # fmt: skip
            for k, u in enumerate(window.uncertainty, start=1):
                if u is not None and k in self.waiting and self._determines(u):
                    del self.waiting[k]  # released: the next window moves it
                    self.released[k], self.tried[k], self.resected[k] = frame, 0, 0
                elif u is not None and k not in held:
                    self.window_covariance[k] = with_unobservable(u.covariance, u.unobservable)
                    drift = self.tracks[k].drifted(frame, self.extrinsics[k], self.window_covariance[k])
                    self.tracks[k].fuse(self.extrinsics[k], self.window_covariance[k])
                    if drift is not None:
                        self._forget_before(k, drift.frame)
                        self.waiting[k] = False
                        changes.append((k, drift))
        registered = len(measured) == len(features)
        return self._state(frame, registered, changes, time.perf_counter() - start)

    def _determines(self, u) -> bool:
        """Whether the window's uncertainty ``u`` (:class:`~ocalib.rigba.covariance.ExtrinsicUncertainty`) of a
        camera releases it: its rotation's 1-sigma under ``release_rotation_deg`` about every axis, its translation's
        under ``release_translation_m`` along the two best-determined directions."""
        rotation = np.degrees(u.rotation_std)
        translation = np.linalg.eigvalsh(with_unobservable(u.covariance, u.unobservable)[3:, 3:])
        return bool(
            np.all(rotation <= self.options.release_rotation_deg)
            and np.sqrt(max(translation[1], 0.0)) <= self.options.release_translation_m
        )

    def _working(self, metric: np.ndarray) -> np.ndarray:
        """The new keyframe's poses (C, 4, 4) from the trajectory's ``metric`` ones: as given where the window holds
        them; where it solves them, moved as the window moved the last keyframe's from its metric pose, until camera
        0's own resection places the rig (:meth:`_resect`)."""
        if not self.options.metric_noise or not self.keyframes:
            return metric
        last = self.keyframes[-1]
        return last.poses[0] @ np.linalg.inv(last.prior) @ metric

    def _features(self, image: np.ndarray, k: int) -> Features:
        """Camera k's SIFT features of ``image``, their keypoints moved to the pinhole pixels of their rays where the
        camera has a lens distortion (the estimator works in pinhole pixels; rays the lens cannot invert dropped)."""
        features = self._extract(image)
        if self.distortions[k] is None:
            return features
        xy = undistort_pixels(features.keypoints, self.K[k], self.distortions[k])
        ok = np.isfinite(xy).all(1)
        return Features(xy[ok], features.descriptors[ok])

    def _resect(self, kf: Keyframe, recent: list[Keyframe], matches) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Each camera's pose from its 2-D-3-D matches with the ``recent`` keyframes (``matches[k][j]``: camera k's
        with keyframe j; COLMAP's absolute pose, at least ``min_inliers`` inliers), whose inliers' point ids are set
        -> per camera resected: its extrinsic as this keyframe measures it (``inverse(rig pose) @ camera pose``) and
        the information (6, 6) its inliers give about it (:func:`~ocalib.rigba.change.information`; NaN with fewer
        than ``min_test_inliers``: not tested)."""
        options = pycolmap.AbsolutePoseEstimationOptions()
        options.ransac.max_error, options.ransac.min_num_trials, options.ransac.random_seed = MAX_ERROR_PX, 100, 0
        measured = {}
        for k, features in enumerate(kf.features):
            xy, xyz, where = [], [], []
            for previous, pairs in zip(recent, matches[k]):
                for i, pid in zip(pairs[:, 0], previous.point_ids[k][pairs[:, 1]]):
                    if pid >= 0 and pid in self.points and kf.point_ids[k][i] < 0:
                        xy.append(features.keypoints[i])
                        xyz.append(self.points[pid])
                        where.append((i, pid))
            if len(xy) < self.options.min_inliers:
                continue
            result = pycolmap.estimate_and_refine_absolute_pose(
                np.asarray(xy) + 0.5, np.asarray(xyz), self._cameras[k], options
            )
            if result is None or int(np.sum(result["inlier_mask"])) < self.options.min_inliers:
                continue
            inliers = np.asarray(result["inlier_mask"], bool)
            for (i, pid), inlier in zip(where, inliers):
                if inlier:
                    kf.point_ids[k][i] = pid
            camera_pose = np.linalg.inv(to_matrix(result["cam_from_world"]))
            xy, xyz = np.asarray(xy)[inliers], np.asarray(xyz)[inliers]
            if k == 0 and self._places_rig(kf):
                kf.poses[:] = camera_pose  # the rig's pose is camera 0's: the extrinsics are measured against it
            extrinsic = np.linalg.inv(kf.poses[k]) @ camera_pose
            info = np.full((6, 6), np.nan)
            if inliers.sum() >= self.options.min_test_inliers:
                info = information(xy, xyz, self.K[k], kf.poses[k], extrinsic)
                if k > 0 and self._places_rig(kf):
                    reference = measured[0][1] if 0 in measured else np.full((6, 6), np.nan)
                    info = relative_information(info, reference, extrinsic)
            measured[k] = extrinsic, info
        return measured

    def _places_rig(self, kf: Keyframe) -> bool:
        """Whether camera 0's resection places keyframe ``kf``'s rig: the window solves the poses (the trajectory's
        noise over 0) and the keyframe's cameras share one pose."""
        return bool(self.options.metric_noise) and shares_pose(kf)

    def _poses(self, kf: Keyframe, measured: dict[int, tuple[np.ndarray, np.ndarray]]) -> list[np.ndarray]:
        """Each camera's ``cam_from_world`` (4, 4) at the new keyframe: where the window puts it, or where its own
        resection does while it disagrees with the window or a change of it is pending (so that a knocked camera's
        new points are where it now looks, and the next keyframes measure the new mounting instead of the old one
        their points would give)."""
        return [
            np.linalg.inv(kf.poses[k] @ (measured[k][0] if k in measured and self._suspect(k) else E))
            for k, E in enumerate(self.extrinsics)
        ]

    def _suspect(self, k: int) -> bool:
        """Whether camera k's keyframes disagree with the window, or a candidate change of it awaits judgement."""
        return self.tracks[k].disagrees or k in self.pending

    def _triangulate(self, kf: Keyframe, recent: list[Keyframe], matches, poses: list[np.ndarray]) -> None:
        """Extend the tracks the new keyframe's matches with the ``recent`` keyframes continue (where the point
        reprojects), and triangulate new points from the others, the latest keyframe first; ``poses`` (C,) the new
        keyframe's cam_from_world (4, 4) per camera."""
        for k, features in enumerate(kf.features):
            new_from_world = poses[k]
            for previous, pairs in reversed(list(zip(recent, matches[k]))):
                i, j = pairs[kf.point_ids[k][pairs[:, 0]] < 0].T
                pid = previous.point_ids[k][j]
                known = np.array([p in self.points for p in pid.tolist()], dtype=bool)
                if known.any():
                    X = np.stack([self.points[p] for p in pid[known].tolist()])
                    ok = self._reprojects(new_from_world, k, X, features.keypoints[i[known]])
                    kf.point_ids[k][i[known][ok]] = pid[known][ok]
                fresh = pid < 0
                if not fresh.any():
                    continue
                old_from_world = np.linalg.inv(previous.poses[k] @ self.extrinsics[k])
                uv = previous.features[k].keypoints[j[fresh]], features.keypoints[i[fresh]]
                X, ok = self._points(old_from_world, new_from_world, k, *uv)
                ids = self._next_point + np.arange(int(ok.sum()))
                self._next_point += len(ids)
                self.points.update(zip(ids.tolist(), X[ok]))
                kf.point_ids[k][i[fresh][ok]] = ids
                previous.point_ids[k][j[fresh][ok]] = ids

    def _points(self, old_from_world, new_from_world, k: int, old_uv: np.ndarray, new_uv: np.ndarray):
        """The 3-D points (n, 3) of keypoints ``old_uv`` and ``new_uv`` (n, 2) of camera k seen from two poses
        (linear triangulation), and which are good (n,): in front of both, seen under ``min_angle_deg`` or more,
        reprojecting within ``MAX_ERROR_PX``."""
        rows = []
        for T, uv in ((old_from_world, old_uv), (new_from_world, new_uv)):
            xy = (np.c_[uv, np.ones(len(uv))] @ np.linalg.inv(self.K[k]).T)[:, :2]
            rows += [xy[:, :1] * T[2] - T[0], xy[:, 1:] * T[2] - T[1]]
        X = np.linalg.svd(np.stack(rows, 1))[2][:, -1]  # (n, 4) homogeneous
        with np.errstate(divide="ignore", invalid="ignore"):
            X = X[:, :3] / X[:, 3:]
        a, b = (X - np.linalg.inv(T)[:3, 3] for T in (old_from_world, new_from_world))
        cosine = (a * b).sum(1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
        ok = np.isfinite(X).all(1) & (cosine <= np.cos(np.radians(self.options.min_angle_deg)))
        ok &= self._reprojects(old_from_world, k, X, old_uv) & self._reprojects(new_from_world, k, X, new_uv)
        return X, ok

    def _reprojects(self, cam_from_world: np.ndarray, k: int, X: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Whether points ``X`` (n, 3) lie in front of camera k at ``cam_from_world`` and reproject within
        ``MAX_ERROR_PX`` of keypoints ``uv`` (n, 2) -> (n,) bool."""
        p = X @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            projected = p @ self.K[k].T
            error = np.linalg.norm(projected[:, :2] / projected[:, 2:] - uv, axis=1)
        return (p[:, 2] > 1e-9) & (error < MAX_ERROR_PX)

    def _evict(self) -> None:
        """Keep the last ``window`` keyframes and the points they observe."""
        while len(self.keyframes) > self.options.window:
            self.keyframes.popleft()
        seen = set()
        for kf in self.keyframes:
            for ids in kf.point_ids:
                seen.update(ids[ids >= 0].tolist())
        for pid in set(self.points) - seen:
            del self.points[pid]

    def _candidates(self, frame: int, measured: dict[int, tuple[np.ndarray, np.ndarray]]) -> list[tuple[int, Change]]:
        """Test each camera's measured extrinsic against the window -> the candidate changes completed."""
        candidates = []
        for k, (extrinsic, info) in measured.items():
            reference = self.extrinsics[k], self.window_covariance[k]
            change = self.tracks[k].observe(frame, extrinsic, info, reference) if k > 0 else None
            if change is not None:
                candidates.append((k, change))
        return candidates

    def _judged(self, frame: int) -> list[tuple[int, Change]]:
        """The pending candidates judged at keyframe ``frame`` by the window's split test, once ``CONFIRM_SPAN``
        keyframes from the candidate's frame on are in the window (two keyframes misled by their matches, as on a
        repeated texture, decide less among four) -> the changes confirmed (noticed at ``frame``)."""
        changes = []
        for k, change in list(self.pending.items()):
            if sum(kf.frame >= change.frame for kf in self.keyframes) >= CONFIRM_SPAN:
                del self.pending[k]
                confirmed = self._confirmed(k, change)
                if confirmed is not None:
                    changes.append((k, replace(confirmed, detected=frame)))
        return changes

    def _confirmed(self, k: int, change: Change) -> Change | None:
        """Whether the window confirms camera k's candidate ``change``: the window's split test at the keyframe
        among the candidate's and the ``SPLIT_SEARCH`` before it where it is largest among the steps of at least
        the least change (the keyframes' test starts a run a keyframe or two after the move, and a split after the
        move keeps moved keyframes on its first side), over its level at ``CONFIRM_FALSE_ALARM`` shared among those splits. Confirmed, the change is dated at that
        keyframe, the camera loses its observations from before it, and it restarts from the candidate's rotation
        (the disagreeing keyframes' mean measurement) with the lever arm it had (a knock turns a camera more than it
        moves it), waiting until the window determines it; its track then takes the next windows' estimates. -> the change
        confirmed, or None."""
        track = self.tracks[k]
        frames = [kf.frame for kf in self.keyframes]
        at = frames.index(change.frame) if change.frame in frames else 0
        tests = [(self._split(k, f), f) for f in frames[max(at - SPLIT_SEARCH, 0) : at + 1]]
        level = chi2_distribution.ppf(1 - CONFIRM_FALSE_ALARM / len(tests), 6)
        split, split_frame = max(
            tests, key=lambda t: (reaches(t[0].step, track.min_change), np.nan_to_num(t[0].statistic, nan=-np.inf))
        )
        if not (split.statistic > level and reaches(split.step, track.min_change)):  # NaN: too little
            track.dismiss()
            self.dismissed.append((k, change.detected, split))
            return None
        change = replace(change, frame=split_frame)
        lever_arm = self.extrinsics[k][:3, 3].copy()
        track.accept(change)
        self.extrinsics[k][:3, :3] = track.extrinsic[:3, :3]
        self.extrinsics[k][:3, 3] = track.extrinsic[:3, 3] = lever_arm
        self._forget_before(k, change.frame)
        self.waiting[k] = False
        return change

    def _split(self, k: int, frame: int) -> SplitTest:
        """The window's split test of camera k moving at keyframe ``frame`` (:func:`split_statistic`)."""
        keyframes, noise = list(self.keyframes), self.options.metric_noise
        return split_statistic(keyframes, self.points, self.extrinsics, self.K, self.sizes, k, frame, noise)

    def _forget_before(self, k: int, frame: int) -> None:
        """Drop camera k's observations before ``frame``: they saw the camera where it no longer is."""
        for kf in self.keyframes:
            if kf.frame < frame:
                kf.point_ids[k][:] = -1

    def _state(self, frame: int, registered: bool, changes, seconds: float) -> RigState:
        C = len(self.K)
        extrinsics = np.tile(np.eye(4), (C, 1, 1))
        std = np.full((C, 6), np.nan)
        std[0] = 0.0
        for k in range(1, C):
            track = self.tracks[k]
            if track.extrinsic is not None:
                extrinsics[k] = track.extrinsic
                variance = np.clip(np.diag(track.covariance), 0, None)
                std[k] = np.where(variance < UNINFORMED / 10, np.sqrt(variance), np.inf)
            else:  # waiting since the start: the head's rotation, no lever arm yet
                extrinsics[k] = self.extrinsics[k]
                extrinsics[k, :3, 3] = np.nan
        chi2 = np.array([t.chi2 for t in self.tracks])
        return RigState(frame, extrinsics, std, chi2, registered, changes, seconds)
