"""KITTI raw's extract product: distorted cameras, each with the frames it kept and stamps of its own."""

import numpy as np
import pytest
from data_fixtures import T_CAM0_VELO, T_VELO_IMU, H, W, kv, noise_image, oxts_packets, pose, rot, write_oxts, write_png

from ocalib.data import open_sequence
from ocalib.data.synchronise import synchronise
from ocalib.errors import InputError

D = [-0.37, 0.20, 0.0012, -0.0006, -0.069]  # k1 k2 p1 p2 k3, as KITTI's grey cameras
T_CAM1_CAM0 = pose(rot(1, 0.01), (-0.54, 0.002, 0.003))  # R_01, T_01: camera 0's points into camera 1's


def stamp(t: float) -> str:
    return f"2011-09-26 13:02:{25.0 + t:012.9f}"


def write_extract(root, dropped=(None, 3), frames=8):
    """A date folder with one extract drive of two cameras at 10 Hz, camera 1 stamping 4 ms late; each camera leaves
    out its frame of ``dropped`` (renumbered: the extract's names are consecutive)."""
    date = root / "2011_09_26"
    drive = date / "2011_09_26_drive_0001_extract"
    calib = "calib_time: 09-Jan-2012 13:57:47\n"
    for i, T in enumerate((np.eye(4), T_CAM1_CAM0)):
        K = np.array([[90.0, 0, W / 2 - 0.5], [0, 90.0, H / 2 - 0.5], [0, 0, 1]])
        calib += kv(**{f"S_0{i}": [W, H], f"K_0{i}": K, f"D_0{i}": D, f"R_0{i}": T[:3, :3], f"T_0{i}": T[:3, 3]})
    date.mkdir(parents=True)
    (date / "calib_cam_to_cam.txt").write_text(calib)
    for i, drop in enumerate(dropped):
        kept = [t for t in range(frames) if t != drop]
        for j, t in enumerate(kept):
            write_png(drive / f"image_0{i}" / "data" / f"{j:010d}.png", noise_image(10 * i + t, grey=True))
        lines = "".join(f"{stamp(t / 10 + 0.004 * i)}\n" for t in kept)
        (drive / f"image_0{i}" / "timestamps.txt").write_text(lines)
    return drive


def test_an_extract_drive_opens_with_its_lenses_extrinsics_and_own_stamps(tmp_path):
    seq = open_sequence(write_extract(tmp_path))
    cam0, cam1 = seq.cameras
    assert (len(cam0), len(cam1)) == (8, 7) and cam1.distortion.model == "opencv"
    np.testing.assert_allclose(cam1.distortion.coeffs, D)
    np.testing.assert_allclose(cam1.T_cam0_cam, np.linalg.inv(T_CAM1_CAM0), atol=1e-9)
    np.testing.assert_allclose(np.diff(cam1.times), [0.1, 0.1, 0.2, 0.1, 0.1, 0.1], atol=1e-6)
    paired = synchronise(seq, [0.0])
    assert paired.pairing.frames.tolist() == [[0, 0], [1, 1], [2, 2], [4, 3], [5, 4], [6, 5], [7, 6]]
    assert paired.pairing.skipped.tolist() == [0, 1]  # camera 0's frame 3: camera 1 dropped it
    np.testing.assert_allclose(paired.pairing.residuals[:, 1], -0.004, atol=1e-6)


def test_an_extract_stamp_count_other_than_the_images_is_one_line(tmp_path):
    drive = write_extract(tmp_path)
    stamps = drive / "image_01" / "timestamps.txt"
    stamps.write_text(stamps.read_text() + stamp(0.95) + "\n")
    with pytest.raises(InputError, match=f"{stamps}: 8 timestamps for 7 images"):
        open_sequence(drive)


def _motion(t: np.ndarray) -> np.ndarray:
    """Camera 0's pose (T, 4, 4) at times ``t`` (s): a constant turn about y and a constant velocity, which
    interpolation between any two samples reproduces exactly."""
    out = np.tile(np.eye(4), (len(t), 1, 1))
    out[:, :3, :3] = [rot(1, 0.05 * s) for s in t]
    out[:, :3, 3] = np.outer(t, [0.3, 0.0, 8.0])
    return out


def test_an_extract_drive_has_each_cameras_poses_at_its_own_stamps_from_the_oxts_packets(tmp_path):
    """OXTS at 100 Hz from 0.05 s before the first frame, packets 0.38-0.44 s missing (a logger gap of 7 periods):
    each camera's poses at its own stamps are the motion's, camera 1's through its extrinsic; frames in the gap NaN."""
    drive = write_extract(tmp_path)
    (drive.parent / "calib_velo_to_cam.txt").write_text(kv(R=T_CAM0_VELO[:3, :3], T=T_CAM0_VELO[:3, 3]))
    (drive.parent / "calib_imu_to_velo.txt").write_text(kv(R=T_VELO_IMU[:3, :3], T=T_VELO_IMU[:3, 3]))
    t = np.round(np.arange(-0.05, 0.8, 0.01), 6)
    t = t[(t < 0.375) | (t > 0.445)]
    write_oxts(drive, oxts_packets(_motion(t) @ T_CAM0_VELO @ T_VELO_IMU))
    (drive / "oxts" / "timestamps.txt").write_text("".join(f"{stamp(s)}\n" for s in t))
    cam0, cam1 = open_sequence(drive).cameras
    gap = (cam0.times - cam0.times[0] > 0.375) & (cam0.times - cam0.times[0] < 0.445)
    assert gap.sum() == 1 and np.isnan(cam0.poses[gap]).all()
    shift = np.eye(4)  # the packets' world: the Mercator frame moved to the first IMU position (-0.05 s)
    shift[:3, 3] = -(_motion(t[:1]) @ T_CAM0_VELO @ T_VELO_IMU)[0, :3, 3]
    for cam in (cam0, cam1):
        expected = shift @ _motion(cam.times - cam0.times[0]) @ cam.T_cam0_cam
        ok = np.isfinite(cam.poses).all((1, 2))
        assert ok.sum() >= len(cam) - 1
        np.testing.assert_allclose(cam.poses[ok][:, :3], expected[ok][:, :3], atol=1e-6)
