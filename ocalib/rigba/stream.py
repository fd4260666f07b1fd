"""The on-line rig estimator (:mod:`ocalib.rigba.online`) as a stage of ``ocalib calibrate``'s stream: called
after the head on every frame, it starts at ``START_FRAME`` from the head's rotations (each camera's following the
head's until the window determines it), reads the frame's images at their own size, and keeps each keyframe's state
for the trace, the plot, TensorBoard and the JSON.

Cameras on clocks of their own (a sequence paired in time) are placed at the rig's pose when each captured its image,
the metric trajectory interpolated there (:func:`capture_poses`), so a pair's residual offset does not bias the lever
arm by the rig's motion in between; where the rig moves less than a fifth of the trajectory's noise between their
captures, they share camera 0's poses, which the window then solves.

Convention: ``metric`` (T, 4, 4) is camera 0's camera-to-world trajectory in metres, re-referenced to its first
frame; extrinsics ``T_cam0_camk`` (``p_cam0 = R p_camk + t``) in metres.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

from ocalib.calib.drivers.result import Calibration, planar_axes
from ocalib.data.sequence import Sequence
from ocalib.errors import InputError
from ocalib.geometry.directions import angle_deg, height_error, projector_without
from ocalib.geometry.quaternion import rotation_matrix_to_quaternion
from ocalib.geometry.se3 import rotation_angle_deg
from ocalib.io.timing import interpolate
from ocalib.rigba.camera_state import Phase
from ocalib.rigba.covariance import WEAK_SHARE
from ocalib.rigba.online import OnlineRigEstimator, OnlineRigOptions, RigState
from ocalib.rigba.trust import MAX_ROTATION_STD_DEG

START_FRAME = 10  # the frame the estimator starts at: the head's rotation needs some motion first
# the share of a camera's keyframes since its release that, unregistered, withholds its estimate (a car's side camera
# at 128x416 misses 30-50 % of its resections with its estimate within the targets: its covariance tells the rest)
UNREGISTERED = 0.75
# a camera whose capture poses lie within this share of the trajectory's noise and NEGLIGIBLE_DEG of camera 0's shares
# them (capture_poses): 1 cm of the default 5 cm
NEGLIGIBLE_SHARE = 0.2
NEGLIGIBLE_DEG = 0.05  # a fifth of a pixel at the renders' 240 px focal length
HELD_HINT = (  # after a change found with the trajectory's poses held: where they are not exact, that is a suspect
    " (the metric trajectory's poses are held as exact: if they are not, their rotation error reads as a move; "
    "give its noise with --metric-noise)"
)


class OnlineRigStage:
    """Call with ``(t, estimate)`` after the head's frame t (estimate: its :class:`Calibration`, rig 0)."""

    def __init__(self, sequence: Sequence, metric: np.ndarray, options: OnlineRigOptions = OnlineRigOptions()):
        self.sequence, self.metric, self.options = sequence, np.linalg.inv(metric[:1]) @ metric, options
        self.capture = capture_poses(sequence, self.metric, (options.metric_noise or 0.0) * NEGLIGIBLE_SHARE)
        self.estimator: OnlineRigEstimator | None = None
        self.start: int | None = None
        self.states: list[RigState] = []
        self.warnings: list[str] = []

    def __call__(self, t: int, estimate: Calibration) -> RigState | None:
        if self.estimator is None and not self._started(t, estimate):
            return None
        images = self._images(t) if self.estimator.keyframe_next else None
        rotations = estimate.rotation[0].double().cpu().numpy()
        state = self.estimator.update(t, images, self.capture[t], rotations)
        if state is not None:
            self.states.append(state)
            for k, change in state.changes:
                self.warnings.append(
                    f"on-line rig estimator: {self.sequence.names[k]}: its extrinsic changed at frame {change.frame} "
                    f"(noticed at frame {change.detected}): {change.rotation_change_deg:.2f} deg, "
                    f"{change.translation_change:.3f} m; the estimate follows the new one"
                    + ("" if self.options.metric_noise else HELD_HINT)
                )
        return state

    def _images(self, t: int) -> list[np.ndarray]:
        """Frame t of every camera, grayscale (H, W) uint8."""
        images = []
        for cam in self.sequence.cameras:
            image = cv2.imread(str(cam.images[t]), cv2.IMREAD_GRAYSCALE)
            if image is None:
                raise InputError(f"{cam.images[t]}: not an image OpenCV can read")
            images.append(image)
        return images

    def _started(self, t: int, estimate: Calibration) -> bool:
        """Start the estimator at the head's rotations from ``START_FRAME`` on, once they are finite."""
        if t < START_FRAME or not bool(torch.isfinite(estimate.rotation).all()):
            return False
        extrinsics = np.tile(np.eye(4), (len(self.sequence.cameras), 1, 1))
        extrinsics[1:, :3, :3] = estimate.rotation[0].double().cpu().numpy()
        K = np.stack([cam.K for cam in self.sequence.cameras])
        sizes = [tuple(cam.size) for cam in self.sequence.cameras]
        distortions = [cam.distortion for cam in self.sequence.cameras]
        self.estimator, self.start = OnlineRigEstimator(K, sizes, extrinsics, self.options, distortions), t
        if self.options.metric_noise and not self.solves_poses:
            self.warnings.append(
                "on-line rig estimator: the cameras were not triggered together, so each is placed at the metric "
                "trajectory's pose when it captured its image, held as given (its noise is not used): an error of "
                "its rotation reads as the cameras moving"
            )
        return True

    def attach(self, result) -> None:
        """Put the estimator into ``result`` (an :class:`~ocalib.calibnet.run.ImageCalibration`): its columns into
        the trace, itself, and its final errors against the truth at the last frame where the sequence has one."""
        frames = len(result.run.trace["frame"])
        result.run.trace.update(self.trace(frames))
        result.rig = self
        for k, change in sorted(self.unjudged().items()):
            self.warnings.append(
                f"on-line rig estimator: {self.sequence.names[k]}: its extrinsic may have changed at frame "
                f"{change.frame} ({change.rotation_change_deg:.2f} deg, {change.translation_change:.3f} m), too close "
                "to the stream's end to be judged; the estimate is the camera's before it: record more frames to tell"
            )
        if self.estimator is not None and self.estimator.windows_without_priors:
            self.warnings.append(
                f"on-line rig estimator: {self.estimator.windows_without_priors} of {self.estimator.windows_solved} "
                "windows could not take the metric trajectory's positions as priors (COLMAP aligns no similarity to "
                "positions on a line, nor to a window farther than three sigmas from them): those were anchored at "
                "two keyframes' poses instead, keeping the scale they had"
            )
        if self.final is None:
            self.warnings.append(
                f"on-line rig estimator: never started (the sequence is shorter than {START_FRAME + 1} frames, or the "
                "on-line head gave no rotation); no on-line translation"
            )
        cameras = self.sequence.cameras
        if self.final is None or any(cam.T_cam0_cam is None for cam in cameras):
            return
        truth = np.stack([cam.T_cam0_cam for cam in cameras])
        for k, cam in enumerate(cameras):
            if cam.change is not None and cam.change.frame < frames:
                truth[k] = cam.change.T_cam0_cam
        result.rig_errors = self.errors(np.linalg.inv(truth[:1]) @ truth, planar_axes(result.run.final))

    @property
    def solves_poses(self) -> bool:
        """Whether the windows solve the rig's poses (camera 0's positions priors) rather than hold the metric
        trajectory's: a noise stated (over 0) and the cameras triggered together (each at its own capture pose
        otherwise, which only held poses allow)."""
        return bool(self.options.metric_noise) and bool((self.capture == self.capture[:, :1]).all())

    @property
    def final(self) -> RigState | None:
        return self.states[-1] if self.states else None

    def steady_extrinsics(self) -> np.ndarray | None:
        """(C, 4, 4) the final extrinsics of the cameras the estimator placed and found steady all run (NaN rows for
        one not placed, its rotation's 1-sigma over ``MAX_ROTATION_STD_DEG`` on an axis, or that moved: the bundle
        adjustment's one extrinsic is not theirs); None before a keyframe."""
        if self.final is None:
            return None
        out = self.final.extrinsics.copy()
        moved = np.isin(np.arange(len(out)), [k for s in self.states for k, _ in s.changes])
        loose = ~(np.degrees(self.final.std[:, :3]).max(1) <= MAX_ROTATION_STD_DEG)  # NaN: not placed
        out[loose | moved] = np.nan
        return out

    def undetermined(self) -> dict[int, str]:
        """Camera k >= 1 -> why its final estimate is not to be reported: the window never determined it, or not
        since its change (:meth:`~ocalib.rigba.camera_state.CameraState.determined`), its rotation's 1-sigma over
        ``MAX_ROTATION_STD_DEG`` on an axis, or ``UNREGISTERED`` of its keyframes since its release unregistered.
        Every camera before the first keyframe. (A translation whose 1-sigma is over the targets is reported, flagged:
        ``ocalib.calibnet.run.not_determined``.)"""
        C = len(self.sequence.cameras)
        if self.final is None:
            return {k: "the estimator never started" for k in range(1, C)}
        out = {}
        for k in range(1, C):
            rotation = np.degrees(self.final.std[k, :3])
            cam = self.estimator.cameras[k]
            tried, registered = cam.tried, cam.registered
            if not cam.determined(self.estimator.release_std) or not np.isfinite(rotation).all():
                changes = cam.track.changes
                when = (
                    f"has not determined it since its change at frame {changes[-1].frame}"
                    if changes
                    else "never determined it"
                )
                out[k] = f"the window {when} (too little motion or too few registered keyframes)"
            elif rotation.max() > MAX_ROTATION_STD_DEG:
                out[k] = f"its rotation's 1-sigma is {rotation.max():.2f} deg (over {MAX_ROTATION_STD_DEG:g})"
            elif tried - registered >= UNREGISTERED * tried > 0:
                out[k] = f"{tried - registered} of its {tried} keyframes since its release did not register"
        return out

    def trace(self, frames: int) -> dict[str, np.ndarray]:
        """Per frame (F = ``frames``), each camera k >= 1's latest estimate: ``rig_quaternion`` (F, K, 4),
        ``rig_translation`` (F, K, 3), ``rig_translation_std`` (F, K, 3), ``rig_chi2`` (F, K), ``rig_phase`` (F, K)
        the code of its :class:`~ocalib.rigba.camera_state.Phase` (1 waiting, 2 tracking, 3 disagreeing, 4
        candidate); NaN before the first keyframe's estimate; ``rig_change_frame`` (F, K): at the frame a change was
        noticed, the first frame that disagreed (NaN elsewhere)."""
        K = len(self.sequence.cameras) - 1
        out = {
            "rig_quaternion": np.full((frames, K, 4), np.nan),
            "rig_translation": np.full((frames, K, 3), np.nan),
            "rig_translation_std": np.full((frames, K, 3), np.nan),
            "rig_chi2": np.full((frames, K), np.nan),
            "rig_phase": np.full((frames, K), np.nan),
            "rig_change_frame": np.full((frames, K), np.nan),
        }
        ends = [s.frame for s in self.states[1:]] + [frames]
        for state, end in zip(self.states, ends):
            rows = slice(state.frame, end)
            out["rig_quaternion"][rows] = _quaternions(state.extrinsics[1:])
            out["rig_translation"][rows] = state.extrinsics[1:, :3, 3]
            out["rig_translation_std"][rows] = state.std[1:, 3:]
            out["rig_chi2"][rows] = state.chi2[1:]
            out["rig_phase"][rows] = [Phase[label.upper()].value for label in state.phases[1:]]
            for k, change in state.changes:
                out["rig_change_frame"][state.frame, k - 1] = change.frame
        return out

    def unjudged(self) -> dict:
        """Camera k -> the candidate change (:class:`~ocalib.calib.drivers.change.Change`) raised too close to the stream's
        end for the window to judge it."""
        return {} if self.estimator is None else self.estimator.candidates

    def changes_json(self) -> list[dict]:
        """The changes found: camera name, first disagreeing frame, frame noticed, size of the step."""
        names = self.sequence.names
        return [
            {
                "camera": names[k],
                "frame": c.frame,
                "detected": c.detected,
                "rotation_change_deg": c.rotation_change_deg,
                "translation_change": c.translation_change,
            }
            for s in self.states
            for k, c in s.changes
        ]

    def result_json(self) -> dict:
        """The estimator's final state and cost: per camera k >= 1 its extrinsic (metres) with 1-sigma and covariance, the
        keyframes, the seconds per keyframe (median) and per frame, the candidate changes the window dismissed
        (the frame they were raised at, the split test's likelihood ratio and step) and those raised too late to
        judge."""
        final, seconds = self.final, [s.seconds for s in self.states]
        doc = {
            "units": "metres",
            "started_at_frame": self.start,
            "keyframes": len(self.states),
            "keyframes_unregistered": 0 if self.estimator is None else self.estimator.keyframes_unregistered,
            "seconds_per_keyframe_median": float(np.median(seconds)) if seconds else None,
            "seconds_per_frame": float(np.sum(seconds) / max(1, self.estimator.frames_seen)) if seconds else None,
            "window_keyframes": self.options.window,
            "keyframe_step": self.options.keyframe_step,
            "rig_poses": "solved" if self.solves_poses else "held",
            "windows_solved": 0 if self.estimator is None else self.estimator.windows_solved,
            "windows_without_priors": 0 if self.estimator is None else self.estimator.windows_without_priors,
            "metric_noise_m": self.options.metric_noise or 0.0,
            "unjudged_changes": [
                {
                    "camera": self.sequence.names[k],
                    "frame": c.frame,
                    "rotation_change_deg": c.rotation_change_deg,
                    "translation_change": c.translation_change,
                }
                for k, c in sorted(self.unjudged().items())
            ],  # fmt: skip
            "dismissed_changes": [
                {
                    "camera": self.sequence.names[k],
                    "frame": frame,
                    "split_statistic": _finite(split.statistic),
                    "rotation_change_deg": _finite(split.rotation_deg),
                    "translation_change": _finite(split.translation),
                }
                for k, frame, split in ([] if self.estimator is None else self.estimator.dismissed)
            ],
            "extrinsics": [],
        }
        if final is None:
            return doc
        for k in range(1, len(final.extrinsics)):
            E, std = final.extrinsics[k], final.std[k]
            doc["extrinsics"].append(
                {
                    "camera": self.sequence.names[k],
                    "rotation": E[:3, :3].tolist(),
                    "quaternion_wxyz": _quaternions(E[None])[0].tolist(),
                    "translation": E[:3, 3].tolist(),
                    "rotation_std_deg": [_finite(math.degrees(v)) for v in std[:3]],
                    "translation_std": [_finite(v) for v in std[3:]],
                    # rotation rad, translation m, camera 0's axes; variances of UNINFORMED where the data say nothing
                    "covariance": None if (P := self.estimator.cameras[k].track.covariance) is None else P.tolist(),
                    "chi2": _finite(final.chi2[k]),
                    "released_at_frame": self.estimator.cameras[k].released_at,
                    # since its release (or the start): the keyframes it was resected at, and of those registered
                    "keyframes_tried": int(self.estimator.cameras[k].tried),
                    "keyframes_registered": int(self.estimator.cameras[k].registered),
                    "source": "rig_estimator",
                }
            )
        return doc

    def errors(self, truth: np.ndarray, plane: np.ndarray | None = None) -> list[dict]:
        """Per camera k >= 1, the final estimate's errors against the true ``truth`` (C, 4, 4) ``T_cam0_camk``
        (after any change), in the keys of :func:`ocalib.calib.poses.report.errors_table`; the translation compared
        without the axes the data do not pin (a 1-sigma over ``WEAK_SHARE`` of the lever arm, or none) and, on a
        planar drive, in the ground plane of normal ``plane`` (C - 1, 3) (NaN rows elsewhere; the error along it is
        ``height_error``), as the bundle adjustment's are; the error over the whole true lever arm, NaN where no
        direction of it is determined."""
        plane = np.full((len(truth) - 1, 3), np.nan) if plane is None else plane
        out = []
        for k in range(1, len(truth)):
            E, T = self.final.extrinsics[k], truth[k]
            loose = ~(self.final.std[k, 3:] <= WEAK_SHARE * np.linalg.norm(E[:3, 3]))
            project = projector_without(np.vstack([np.eye(3)[loose], plane[k - 1]]))
            t, t_true, rank = project @ E[:3, 3], project @ T[:3, 3], round(float(np.trace(project)))  # its rank
            baseline = float(np.linalg.norm(T[:3, 3]))  # the whole lever arm, whatever is compared
            error = float(np.linalg.norm(t - t_true)) if rank else math.nan  # nothing determined: no error
            out.append(
                {
                    "camera": k,
                    "rotation_error_deg": float(rotation_angle_deg(E[:3, :3].T @ T[:3, :3])),
                    "translation_direction_error_deg": angle_deg(t, t_true) if rank >= 2 else math.nan,
                    "compared_in_plane": rank < 3,
                    "metric_scale": 1.0,
                    "translation_error": error,
                    "translation_error_rel_baseline": error / baseline if baseline > 0 else math.nan,
                    "height_error": height_error(E[:3, 3], T[:3, 3], plane[k - 1]),
                }
            )
        return out


def capture_poses(sequence: Sequence, metric: np.ndarray, negligible_m: float = 0.0) -> np.ndarray:
    """(T, C, 4, 4) the rig's metric pose when each camera captured its frame t: camera 0's ``metric`` (T, 4, 4) at
    frame t; for a camera on a clock of its own (``sequence.pairing``), ``metric`` interpolated at its capture time
    ``t0 - residual`` (SLERP and linear, between camera 0's neighbouring frames; where that time lies outside them,
    camera 0's pose at frame t), unless the rig moves less than ``negligible_m`` metres and ``NEGLIGIBLE_DEG``
    between the two capture times at every frame: that camera then shares camera 0's poses (stamps a few
    milliseconds apart, an offset under the trajectory's own noise, are no reason to give up solving the rig's poses)."""
    T, C = len(metric), len(sequence.cameras)
    out = np.repeat(metric[:, None], C, axis=1)
    pairing = sequence.pairing
    if pairing is None or sequence.times is None or T < 2:
        return out
    times = sequence.times[:T]
    period = float(np.median(np.diff(times)))
    for k in range(1, C):
        residual = pairing.residuals[:T, k]
        if not np.any(residual):
            continue
        try:
            kept, poses, _ = interpolate(times - residual, times, metric, period, names=(sequence.names[k], "metric"))
        except InputError:  # capture times out of order or outside camera 0's: its poses as they are
            continue
        good = np.isfinite(poses).all(axis=(1, 2))
        if _apart(poses[good], metric[kept[good]], negligible_m):
            out[kept[good], k] = poses[good]
    return out


def _apart(a: np.ndarray, b: np.ndarray, metres: float) -> bool:
    """Whether poses ``a`` and ``b`` (N, 4, 4) differ somewhere by ``metres`` or more, or by ``NEGLIGIBLE_DEG``."""
    moved = np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1)
    turned = rotation_angle_deg(a[:, :3, :3].transpose(0, 2, 1) @ b[:, :3, :3])
    return bool(np.any(moved >= metres) or np.any(turned >= NEGLIGIBLE_DEG))


def _quaternions(E: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (w >= 0) of the rotations of ``E`` (N, 4, 4)."""
    return rotation_matrix_to_quaternion(torch.from_numpy(np.ascontiguousarray(E[:, :3, :3]))).numpy()


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None
