"""Writers of tiny sequences in every layout the loaders read (24x80 images), with the truth they encode."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ocalib.data.kitti_raw import poses_to_oxts
from ocalib.data.rig import CameraSpec, RigSpec, write_rig_yaml
from ocalib.io.poses import write_kitti

H, W = 24, 80
K = np.array([[50.0, 0, 39.5], [0, 50.0, 11.5], [0, 0, 1]])
EARTH_RADIUS = 6378137.0


def rot(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def pose(R=np.eye(3), t=(0, 0, 0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def trajectory(n: int) -> np.ndarray:
    """Camera-to-world poses (n, 4, 4) of a camera moving forward (z) and turning (about y)."""
    return np.stack([pose(rot(1, 0.05 * t) @ rot(0, 0.01 * t), (0.1 * t, 0.02 * t, 1.0 * t)) for t in range(n)])


def noise_image(seed: int, grey: bool = False, size=(H, W)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, size if grey else (*size, 3), dtype=np.uint8)


def write_png(path: Path, array: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), array)
    return path


def write_rig(root: Path, n: int = 5, names=("cam0", "cam1"), depth: bool = True) -> dict:
    """Native rig layout; camera 1 looks backwards 0.5 m behind camera 0."""
    root.mkdir(parents=True, exist_ok=True)
    extrinsics = [pose(), pose(rot(1, np.pi), (0.2, 0.0, -0.5))][: len(names)]
    write_rig_yaml(root / "rig.yaml", RigSpec([CameraSpec(nm, W, H, K, T) for nm, T in zip(names, extrinsics)], 10.0))
    poses0 = trajectory(n)
    (root / "times.txt").write_text("".join(f"{0.1 * t:.6f}\n" for t in range(n)))
    for c, (name, T) in enumerate(zip(names, extrinsics)):
        for t in range(n):
            write_png(root / name / "images" / f"{t:06d}.png", noise_image(100 * c + t))
            if depth:
                write_png(root / name / "depth" / f"{t:06d}.png", np.full((H, W), 256 * (t + 2), np.uint16))
        write_kitti(root / name / "poses.txt", poses0 @ T)
    return {"poses0": poses0, "extrinsics": extrinsics}


# --- KITTI raw -------------------------------------------------------------------------------------------
BASELINES = {0: 0.0, 1: 0.54, 2: -0.06, 3: 0.48}  # rectified camera positions along x in camera 0's frame
R_RECT = rot(0, 0.01) @ rot(1, -0.007)
T_VELO_IMU = pose(rot(2, 0.003) @ rot(0, 0.015), (-0.81, 0.32, -0.80))
T_CAM0_VELO = pose(np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]]) @ rot(2, 0.01), (-0.004, -0.076, -0.27))


def kv(**entries) -> str:
    return "".join(f"{k}: {' '.join(f'{v:.12e}' for v in np.ravel(a))}\n" for k, a in entries.items())


def projection(cam: int) -> np.ndarray:
    """P = K [I | t], t = -position: KITTI's P[0, 3] = -fx b."""
    return K @ np.hstack([np.eye(3), -np.array([[BASELINES[cam]], [0], [0]])])


oxts_packets = poses_to_oxts  # IMU poses in the Mercator frame -> (n, 30) packets


def write_oxts(drive: Path, packets: np.ndarray) -> None:
    for t, p in enumerate(packets):
        path = drive / "oxts" / "data" / f"{t:010d}.txt"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(" ".join(f"{v:.15g}" for v in p) + "\n")


def write_kitti_raw(
    root: Path,
    n: int = 4,
    calib_beside: bool = True,
    cams=(0, 1, 2, 3),
    T_cam0_velo=T_CAM0_VELO,
    T_velo_imu=T_VELO_IMU,
    R_rect=R_RECT,
) -> dict:
    """A date folder with one drive; camera 0 follows :func:`trajectory` (in the Mercator world frame)."""
    date = root / "2011_09_26"
    drive = date / "2011_09_26_drive_0001_sync"
    calib_dir = date if calib_beside else drive
    calib_dir.mkdir(parents=True, exist_ok=True)
    cam_calib = "calib_time: 09-Jan-2012 13:57:47\ncorner_dist: 9.950000e-02\n"
    for i in range(4):
        cam_calib += kv(
            **{f"S_rect_0{i}": [W, H], f"R_rect_0{i}": R_rect if i == 0 else np.eye(3), f"P_rect_0{i}": projection(i)}
        )
    (calib_dir / "calib_cam_to_cam.txt").write_text(cam_calib)
    (calib_dir / "calib_velo_to_cam.txt").write_text(
        "calib_time: 15-Mar-2012 11:37:16\n" + kv(R=T_cam0_velo[:3, :3], T=T_cam0_velo[:3, 3])
    )
    (calib_dir / "calib_imu_to_velo.txt").write_text(
        "calib_time: 25-May-2012 16:47:16\n" + kv(R=T_velo_imu[:3, :3], T=T_velo_imu[:3, 3])
    )
    for i in cams:
        for t in range(n):
            write_png(drive / f"image_0{i}" / "data" / f"{t:010d}.png", noise_image(10 * i + t, grey=i < 2))
        (drive / f"image_0{i}" / "timestamps.txt").write_text(
            "".join(f"2011-09-26 13:02:{25.964389445 + 0.1036 * t:012.9f}\n" for t in range(n))
        )
    poses_cam0 = trajectory(n)  # rectified camera 0 in the world
    T_rect0_imu = pose(R_rect) @ T_cam0_velo @ T_velo_imu
    write_oxts(drive, oxts_packets(poses_cam0 @ T_rect0_imu))
    return {"drive": drive, "poses0": poses_cam0}


# --- KITTI odometry --------------------------------------------------------------------------------------
def write_kitti_odometry(root: Path, n: int = 4, seq: str = "00", with_poses: bool = True) -> Path:
    folder = root / "dataset" / "sequences" / seq
    folder.mkdir(parents=True)
    (folder / "calib.txt").write_text(
        "".join(f"P{i}: {' '.join(f'{v:.12e}' for v in projection(i).ravel())}\n" for i in range(4))
        + "Tr: "
        + " ".join(["0"] * 12)
        + "\n"
    )
    (folder / "times.txt").write_text("".join(f"{0.1 * t:.6e}\n" for t in range(n)))
    for i in range(4):
        for t in range(n):
            write_png(folder / f"image_{i}" / f"{t:06d}.png", noise_image(7 * i + t, grey=i < 2))
    if with_poses:
        write_kitti(root / "dataset" / "poses" / f"{seq}.txt", trajectory(n))
    return folder


# --- SfMLearner and plain folders -------------------------------------------------------------------------
def write_sfmlearner(root: Path, scenes=("s1_02", "s2_02", "s3_03"), n: int = 4, val=("s3_03",)) -> Path:
    for k, scene in enumerate(scenes):
        for t in range(n):
            write_png(root / scene / f"{t:010d}.jpg", noise_image(50 * k + t))
        np.savetxt(root / scene / "cam.txt", K)
    (root / "train.txt").write_text("".join(f"{s}\n" for s in scenes if s not in val))
    (root / "val.txt").write_text("".join(f"{s}\n" for s in val))
    return root


def write_folder(folder: Path, n: int = 4, intrinsics: str = "intrinsics.yaml", text: str | None = None) -> Path:
    for t in range(n):
        write_png(folder / f"frame_{t + 1}.png", noise_image(t, grey=True))
    default = (
        "fx: 50.0\nfy: 50.0\ncx: 39.5\ncy: 11.5\n"
        if intrinsics.endswith((".yaml", ".yml"))
        else "\n".join(" ".join(str(v) for v in row) for row in K)
    )
    (folder / intrinsics).write_text(text if text is not None else default)
    return folder
