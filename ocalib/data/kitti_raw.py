"""Loader of a KITTI raw drive folder (``2011_09_26/2011_09_26_drive_0001_sync``, or ``..._extract``).

```
DRIVE/image_00..03/data/0000000000.png, DRIVE/image_0x/timestamps.txt
DRIVE/oxts/data/0000000000.txt          # GPS/IMU packets -> ground-truth poses (extract: oxts/timestamps.txt too)
calib_cam_to_cam.txt                    # P_rect_0x, R_rect_00, S_rect_0x; in DRIVE or its date folder
                                        # extract: S_0x, K_0x, D_0x (k1 k2 p1 p2 k3), R_0x, T_0x
calib_velo_to_cam.txt, calib_imu_to_velo.txt   # optional: without them there are no camera poses
```

The *extract* product (a drive folder named ``..._extract``) holds the cameras as they were: unrectified, distorted
(OpenCV's model, ``D_0x``), each with the frames it kept and its own stamps (``image_0x/timestamps.txt``), paired in
time by :func:`ocalib.data.synchronise.synchronise`; ``R_0x``, ``T_0x`` map camera 0's points into camera x's
(``p_camx = R p_cam0 + T``). Its OXTS packets (100 Hz, stamped, with gaps where the logger dropped some) give each
camera's poses at its own stamps, interpolated between the packets around it (:func:`ocalib.io.timing.interpolate`,
within ``INTERPOLATION_MAX_DT_PERIODS`` of their period); NaN where no packets are near.

Convention: cameras of a sync drive are the *rectified* ones; the first present (``image_00``, grey left) is the reference,
the others are translated from rectified camera 0 as their projection matrices say (``P_rect_0x = K [I | t]``). The world
frame is the OXTS Mercator frame (x east, y north, z up) shifted to the first IMU position (as pykitti).
Camera pose = IMU pose @ T_imu_cam, T_cam_imu = T_cami_cam0 R_rect_00 T_cam0_velo T_velo_imu (extract: the unrectified
camera 0, ``T_cam0_imu = T_cam0_velo T_velo_imu``, without R_rect_00).
"""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ocalib.data.distortion import Distortion
from ocalib.data.image_io import image_size, list_frames, read_numbers
from ocalib.data.intrinsics import intrinsics_from_projection
from ocalib.data.sequence import Camera, Sequence
from ocalib.errors import InputError, read_text
from ocalib.io.timing import INTERPOLATION_MAX_DT_PERIODS, increasing, interpolate

EARTH_RADIUS = 6378137.0  # metres, as the KITTI devkit


def read_calib_file(path: str | Path) -> dict[str, tuple[int, str]]:
    """A ``key: values`` calibration file -> {key: (line number, values text)}; parse with :func:`calib_matrix`."""
    path = Path(path)
    entries = {}
    for lineno, line in enumerate(read_text(path, "calibration file").splitlines(), 1):
        if not line.strip():
            continue
        key, sep, value = line.partition(":")
        if not sep:
            raise InputError(f"{path}:{lineno}: expected 'key: values', got {line.strip()[:60]!r}")
        entries[key.strip()] = (lineno, value)
    return entries


def calib_matrix(path: Path, entries: dict, key: str, shape: tuple[int, ...]) -> np.ndarray:
    """The entry ``key`` of a calibration file as a float64 array of ``shape``; errors name file and line."""
    if key not in entries:
        raise InputError(f"{path}: no entry {key!r}")
    lineno, text = entries[key]
    try:
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}:{lineno}: {key} holds something that is not a number") from None
    if values.size != int(np.prod(shape)) or not np.isfinite(values).all():
        raise InputError(f"{path}:{lineno}: {key} needs {int(np.prod(shape))} finite numbers, got {values.size}")
    return values.reshape(shape)


def _rigid(path: Path) -> np.ndarray:
    """``R:`` and ``T:`` entries of a KITTI rigid calibration file -> (4, 4) float64."""
    entries = read_calib_file(path)
    T = np.eye(4)
    T[:3, :3] = calib_matrix(path, entries, "R", (3, 3))
    T[:3, 3] = calib_matrix(path, entries, "T", (3,))
    return T


def oxts_to_poses(packets: np.ndarray) -> np.ndarray:
    """OXTS packets (N, >=6: lat, lon [deg], alt [m], roll, pitch, yaw [rad]) -> IMU poses (N, 4, 4).

    The KITTI devkit conversion: Mercator with the scale of the first latitude, R = Rz(yaw) Ry(pitch) Rx(roll);
    translations are shifted so that the first IMU position is the origin.
    """
    lat, lon, alt, roll, pitch, yaw = packets[:, :6].T
    scale = np.cos(np.deg2rad(lat[0]))
    t = np.stack(
        [
            scale * EARTH_RADIUS * np.deg2rad(lon),
            scale * EARTH_RADIUS * np.log(np.tan(np.deg2rad(90.0 + lat) / 2)),
            alt,
        ],
        -1,
    )
    poses = np.tile(np.eye(4), (len(packets), 1, 1))
    poses[:, :3, :3] = _rot(yaw, 2) @ _rot(pitch, 1) @ _rot(roll, 0)
    poses[:, :3, 3] = t - t[0]
    return poses


def poses_to_oxts(imu_poses: np.ndarray, lat0: float = 49.0) -> np.ndarray:
    """IMU poses (N, 4, 4) in a Mercator frame about latitude ``lat0`` (deg) -> OXTS packets (N, 30) (lat, lon, alt,
    roll, pitch, yaw; the rest zero): the inverse of :func:`oxts_to_poses` up to its shift to the first position, for
    writing a drive in KITTI's layout."""
    scale = np.cos(np.deg2rad(lat0))
    y0 = scale * EARTH_RADIUS * np.log(np.tan(np.deg2rad(90 + lat0) / 2))
    x, y, z = (imu_poses[:, :3, 3] + [0.0, y0, 0.0]).T
    R = imu_poses[:, :3, :3]
    packets = np.zeros((len(imu_poses), 30))
    packets[:, 0] = np.rad2deg(2 * np.arctan(np.exp(y / (scale * EARTH_RADIUS)))) - 90
    packets[:, 1] = np.rad2deg(x / (scale * EARTH_RADIUS))
    packets[:, 2] = z
    packets[:, 3:6] = np.stack(
        [np.arctan2(R[:, 2, 1], R[:, 2, 2]), -np.arcsin(R[:, 2, 0]), np.arctan2(R[:, 1, 0], R[:, 0, 0])], 1
    )
    return packets


def _rot(angle: np.ndarray, axis: int) -> np.ndarray:
    """Rotations (N, 3, 3) by ``angle`` (N,) about coordinate axis 0, 1 or 2."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.tile(np.eye(3), (len(angle), 1, 1))
    R[:, i, i], R[:, i, j], R[:, j, i], R[:, j, j] = c, -s, s, c
    return R


def read_timestamps(path: Path) -> np.ndarray:
    """KITTI ``timestamps.txt`` (``2011-09-26 13:02:25.964389445``) -> (N,) float64 seconds since the epoch (UTC)."""
    times = []
    for lineno, line in enumerate(read_text(path, "timestamps file").splitlines(), 1):
        if not line.strip():
            continue
        try:
            day, clock = line.split()
            hms, _, fraction = clock.partition(".")
            whole = datetime.strptime(f"{day} {hms}", "%Y-%m-%d %H:%M:%S").replace(tzinfo=timezone.utc)
            times.append(whole.timestamp() + float(f"0.{fraction or 0}"))
        except ValueError:
            raise InputError(
                f"{path}:{lineno}: expected 'YYYY-MM-DD HH:MM:SS.fraction', got {line.strip()[:40]!r}"
            ) from None
    return np.asarray(times)


def _read_packet(path: Path) -> np.ndarray:
    values = read_numbers(path)[0]
    if values.size < 6:
        raise InputError(
            f"{path}: an OXTS packet needs at least lat, lon, alt, roll, pitch, yaw; got {values.size} numbers"
        )
    return values[:6]


def _calib_path(drive: Path, name: str) -> Path | None:
    for folder in (drive, drive.parent):
        if (folder / name).is_file():
            return folder / name
    return None


def open_kitti_raw(path: str | Path) -> Sequence:
    """Open a KITTI raw drive folder ``path`` (holding ``image_0x/data``): rectified cameras with ground truth."""
    drive = Path(path)
    cam_file = _calib_path(drive, "calib_cam_to_cam.txt")
    if cam_file is None:
        raise InputError(f"{drive}: no calib_cam_to_cam.txt in the drive folder or beside it")
    calib = read_calib_file(cam_file)
    folders = [drive / f"image_0{i}" for i in range(4) if (drive / f"image_0{i}" / "data").is_dir()]
    if not folders:
        raise InputError(f"{drive}: no image_00..image_03/data folders")
    if drive.name.endswith("_extract"):
        sequence = Sequence(drive.name, drive, "kitti_raw", [_extract_camera(f, cam_file, calib) for f in folders])
        sequence.times = sequence.cameras[0].times
        _extract_poses(drive, sequence)
        return sequence.select(sequence.names)  # extrinsics relative to the first camera present
    cameras = []
    for folder in folders:
        i = folder.name[-2:]
        K, T_cam0_cam = intrinsics_from_projection(calib_matrix(cam_file, calib, f"P_rect_{i}", (3, 4)))
        images = list_frames(folder / "data")
        if f"S_rect_{i}" in calib:
            width, height = calib_matrix(cam_file, calib, f"S_rect_{i}", (2,))
            size = (int(round(height)), int(round(width)))
        else:
            size = image_size(images[0])
        cameras.append(Camera(folder.name, images, K, size, T_cam0_cam))
    sequence = Sequence(drive.name, drive, "kitti_raw", cameras)

    stamps = folders[0] / "timestamps.txt"
    if stamps.is_file():
        sequence.times = read_timestamps(stamps)
        if len(sequence.times) != len(sequence):
            raise InputError(f"{stamps}: {len(sequence.times)} timestamps for {len(sequence)} frames")

    velo_file, imu_file = _calib_path(drive, "calib_velo_to_cam.txt"), _calib_path(drive, "calib_imu_to_velo.txt")
    if (drive / "oxts" / "data").is_dir() and velo_file and imu_file:
        files = list_frames(drive / "oxts" / "data", (".txt",))
        if len(files) != len(sequence):
            raise InputError(f"{drive / 'oxts' / 'data'}: {len(files)} packets for {len(sequence)} frames")
        packets = np.stack([_read_packet(f) for f in files])
        R_rect = np.eye(4)
        R_rect[:3, :3] = calib_matrix(cam_file, calib, "R_rect_00", (3, 3))
        T_cam0_imu = R_rect @ _rigid(velo_file) @ _rigid(imu_file)
        T_w_cam0 = oxts_to_poses(packets) @ np.linalg.inv(T_cam0_imu)
        for cam in sequence.cameras:
            cam.poses = T_w_cam0 @ cam.T_cam0_cam
    return sequence.select(sequence.names)  # extrinsics relative to the first camera present


def _extract_camera(folder: Path, cam_file: Path, calib: dict) -> Camera:
    """Camera ``image_0x`` of an extract drive: its distorted frames (numbering gaps are dropped frames), their own
    stamps, K_0x, D_0x and S_0x, and ``T_cam0_cam`` the inverse of ``[R_0x | T_0x]``."""
    i = folder.name[-2:]
    T_cam_cam0 = np.eye(4)
    T_cam_cam0[:3, :3] = calib_matrix(cam_file, calib, f"R_{i}", (3, 3))
    T_cam_cam0[:3, 3] = calib_matrix(cam_file, calib, f"T_{i}", (3,))
    width, height = calib_matrix(cam_file, calib, f"S_{i}", (2,))
    distortion = Distortion("opencv", tuple(float(d) for d in calib_matrix(cam_file, calib, f"D_{i}", (5,))))
    images = list_frames(folder / "data", gaps=True)
    stamps = folder / "timestamps.txt"
    times = increasing(read_timestamps(stamps), str(stamps))
    if len(times) != len(images):
        raise InputError(f"{stamps}: {len(times)} timestamps for {len(images)} images in {folder / 'data'}")
    K = calib_matrix(cam_file, calib, f"K_{i}", (3, 3))
    size = (int(round(height)), int(round(width)))
    return Camera(folder.name, images, K, size, np.linalg.inv(T_cam_cam0), distortion=distortion, times=times)


def _extract_poses(drive: Path, sequence: Sequence) -> None:
    """Set every camera's poses (N_k, 4, 4) of an extract drive at its own stamps from the OXTS packets (where the
    drive has them, their stamps and the velodyne and IMU calibrations); NaN where the packets do not reach.
    Convention: ``T_cam0_imu = T_cam0_velo T_velo_imu``, camera 0 unrectified; camera k at ``T_w_cam0 T_cam0_camk``."""
    velo_file, imu_file = _calib_path(drive, "calib_velo_to_cam.txt"), _calib_path(drive, "calib_imu_to_velo.txt")
    oxts, stamps = drive / "oxts" / "data", drive / "oxts" / "timestamps.txt"
    if not (oxts.is_dir() and stamps.is_file() and velo_file and imu_file):
        return
    files = list_frames(oxts, (".txt",), gaps=True)
    times = increasing(read_timestamps(stamps), str(stamps))
    if len(times) != len(files):
        raise InputError(f"{stamps}: {len(times)} timestamps for {len(files)} packets in {oxts}")
    T_w_cam0 = oxts_to_poses(np.stack([_read_packet(f) for f in files])) @ np.linalg.inv(
        _rigid(velo_file) @ _rigid(imu_file)
    )
    max_dt = INTERPOLATION_MAX_DT_PERIODS * float(np.median(np.diff(times)))
    for cam in sequence.cameras:
        poses = np.full((len(cam), 4, 4), np.nan)
        kept, at, _ = interpolate(cam.times, times, T_w_cam0, max_dt, names=(cam.name, str(stamps)))
        poses[kept] = at @ cam.T_cam0_cam
        cam.poses = poses
