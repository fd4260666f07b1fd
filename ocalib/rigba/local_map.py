"""The on-line rig estimator's local map (:mod:`ocalib.rigba.online`): the last ``window`` keyframes and the 3-D
points they observe, in memory that does not grow with the sequence. A new keyframe's features are extracted
(:mod:`ocalib.rigba.features`) and matched to the same camera's ``match_previous`` latest keyframes
(:meth:`LocalMap.match`); each camera is resected from its 2-D-3-D matches (:meth:`LocalMap.resect`, COLMAP's
absolute pose), which gives that keyframe's own measurement of its extrinsic; the tracks the matches extend are
continued and new points triangulated (:meth:`LocalMap.triangulate`); :meth:`LocalMap.add` keeps the last
``window`` keyframes and their points, and :meth:`LocalMap.forget` drops a moved camera's old observations.

Convention: poses camera-to-world (4, 4); ``extrinsics`` (C, 4, 4) ``T_cam0_camk``; K (C, 3, 3) in ocalib's pixels
(integer centres); images grayscale (H, W) uint8.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np
import pycolmap

from ocalib.data.distortion import Distortion, undistort_pixels
from ocalib.rigba.change import information, relative_information
from ocalib.rigba.colmap import pinhole_params, to_matrix
from ocalib.rigba.features import Features, SiftExtractor, match_features
from ocalib.rigba.window import MAX_ERROR_PX, Keyframe, shares_pose

if TYPE_CHECKING:
    from ocalib.rigba.online import OnlineRigOptions

# per camera resected: its extrinsic as the keyframe measures it (4, 4) and the information (6, 6) about it
Measured = dict[int, tuple[np.ndarray, np.ndarray]]


class LocalMap:
    """The keyframes (a deque of :class:`~ocalib.rigba.window.Keyframe`) and ``points`` (point id -> (3,)) of the
    window. K (C, 3, 3), ``sizes`` (C,) of (height, width) and ``distortions`` (C,) (None: pinhole) are the
    cameras'."""

    def __init__(
        self,
        K: np.ndarray,
        sizes: list[tuple[int, int]],
        options: OnlineRigOptions,
        distortions: list[Distortion | None],
    ):
        self.K, self.sizes, self.options, self.distortions = K, sizes, options, distortions
        self.keyframes: deque[Keyframe] = deque()
        self.points: dict[int, np.ndarray] = {}
        self._next_point = 0
        self._extract = SiftExtractor(options.max_features, max_width=options.sift_max_width)
        self._cameras = [
            pycolmap.Camera(model="PINHOLE", width=w, height=h, params=pinhole_params(k), camera_id=i + 1)
            for i, (k, (h, w)) in enumerate(zip(self.K, self.sizes))
        ]

    def keyframe(self, frame: int, images: list[np.ndarray], pose: np.ndarray) -> Keyframe:
        """A new keyframe (not yet added) of ``images`` (one per camera): their features, no point yet, and its
        poses (C, 4, 4) from the trajectory's ``pose`` (camera 0's (4, 4), or the rig's (C, 4, 4) at each camera's
        capture, :meth:`working_poses`)."""
        features = [self.features(image, k) for k, image in enumerate(images)]
        poses = np.broadcast_to(np.asarray(pose, np.float64), (len(images), 4, 4)).copy()
        return Keyframe(frame, self.working_poses(poses), features, [np.full(len(f), -1) for f in features],
                        poses[0].copy())  # fmt: skip

    def features(self, image: np.ndarray, k: int) -> Features:
        """Camera k's SIFT features of ``image``, their keypoints moved to the pinhole pixels of their rays where the
        camera has a lens distortion (the estimator works in pinhole pixels; rays the lens cannot invert dropped)."""
        features = self._extract(image)
        if self.distortions[k] is None:
            return features
        xy = undistort_pixels(features.keypoints, self.K[k], self.distortions[k])
        ok = np.isfinite(xy).all(1)
        return Features(xy[ok], features.descriptors[ok])

    def working_poses(self, metric: np.ndarray) -> np.ndarray:
        """The new keyframe's poses (C, 4, 4) from the trajectory's ``metric`` ones: as given where the window holds
        them; where it solves them, moved as the window moved the last keyframe's from its metric pose, until camera
        0's own resection places the rig (:meth:`resect`)."""
        if not self.options.metric_noise or not self.keyframes:
            return metric
        last = self.keyframes[-1]
        return last.poses[0] @ np.linalg.inv(last.prior) @ metric

    def match(self, kf: Keyframe) -> tuple[list[Keyframe], list]:
        """The ``match_previous`` latest keyframes, and the new keyframe ``kf``'s matches with them: ``matches[k][j]``
        camera k's with keyframe j."""
        recent = list(self.keyframes)[-self.options.match_previous :]
        matches = [[match_features(f.descriptors, p.features[k].descriptors) for p in recent] for k, f in
                   enumerate(kf.features)]  # fmt: skip
        return recent, matches

    def resect(self, kf: Keyframe, recent: list[Keyframe], matches) -> Measured:
        """Each camera's pose from its 2-D-3-D matches with the ``recent`` keyframes (:meth:`match`; COLMAP's
        absolute pose, at least ``min_inliers`` inliers), whose inliers' point ids are set -> per camera resected: its
        extrinsic as this keyframe measures it (``inverse(rig pose) @ camera pose``) and the information (6, 6) its
        inliers give about it (:func:`~ocalib.rigba.change.information`; NaN with fewer than ``min_test_inliers``:
        not tested)."""
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

    def triangulate(
        self, kf: Keyframe, recent: list[Keyframe], matches, poses: list[np.ndarray], extrinsics: np.ndarray
    ) -> None:
        """Extend the tracks the new keyframe's matches with the ``recent`` keyframes continue (where the point
        reprojects), and triangulate new points from the others, the latest keyframe first; ``poses`` (C,) the new
        keyframe's cam_from_world (4, 4) per camera, ``extrinsics`` (C, 4, 4) where the window puts the cameras on
        the earlier keyframes."""
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
                old_from_world = np.linalg.inv(previous.poses[k] @ extrinsics[k])
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

    def add(self, kf: Keyframe) -> None:
        """Add keyframe ``kf``; keep the last ``window`` keyframes and the points they observe."""
        self.keyframes.append(kf)
        while len(self.keyframes) > self.options.window:
            self.keyframes.popleft()
        seen = set()
        for keyframe in self.keyframes:
            for ids in keyframe.point_ids:
                seen.update(ids[ids >= 0].tolist())
        for pid in set(self.points) - seen:
            del self.points[pid]

    def forget(self, k: int, frame: int) -> None:
        """Drop camera k's observations before ``frame``: they saw the camera where it no longer is."""
        for kf in self.keyframes:
            if kf.frame < frame:
                kf.point_ids[k][:] = -1
