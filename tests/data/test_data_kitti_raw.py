"""The OXTS conversion against facts of the world, independent of the fixture's inverse conversion."""

import numpy as np
from data_fixtures import EARTH_RADIUS, pose, write_kitti_raw, write_oxts

from ocalib.data import open_sequence
from ocalib.data.kitti_raw import oxts_to_poses

LAT0 = 49.011


def test_driving_north_is_forward_when_heading_north():
    """10 m north with yaw = 90 deg (x forward points north) is 10 m along the IMU's x axis."""
    dlat = np.rad2deg(10.0 / EARTH_RADIUS)
    packets = np.array([[LAT0, 8.4, 110.0, 0, 0, np.pi / 2], [LAT0 + dlat, 8.4, 110.0, 0, 0, np.pi / 2]])
    poses = oxts_to_poses(packets)
    np.testing.assert_allclose(poses[0, :3, 3], 0, atol=1e-9)  # the first IMU position is the origin
    np.testing.assert_allclose((np.linalg.inv(poses[0]) @ poses[1])[:3, 3], [10, 0, 0], atol=1e-3)


def test_climb_and_roll():
    """2 m up with pitch 0 is +z; a roll of 0.1 rad is a rotation about the forward (x) axis."""
    packets = np.array([[LAT0, 8.4, 110.0, 0.0, 0, 0], [LAT0, 8.4, 112.0, 0.1, 0, 0]])
    rel = np.linalg.inv(oxts_to_poses(packets)[0]) @ oxts_to_poses(packets)[1]
    np.testing.assert_allclose(rel[:3, 3], [0, 0, 2], atol=1e-9)
    np.testing.assert_allclose(rel[:3, :3] @ [1, 0, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(rel[1:3, 1:3], [[np.cos(0.1), -np.sin(0.1)], [np.sin(0.1), np.cos(0.1)]], atol=1e-12)


def test_camera_moves_along_its_optical_axis(tmp_path):
    """With KITTI's axes (velodyne x forward, camera z forward), 10 m of driving east with yaw 0 moves
    every camera 10 m along its z axis."""
    axes = pose(np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]]))
    truth = write_kitti_raw(tmp_path, n=2, T_cam0_velo=axes, T_velo_imu=np.eye(4), R_rect=np.eye(3))
    dlon = np.rad2deg(10.0 / (EARTH_RADIUS * np.cos(np.deg2rad(LAT0))))
    write_oxts(truth["drive"], np.array([[LAT0, 8.4, 110, 0, 0, 0], [LAT0, 8.4 + dlon, 110, 0, 0, 0]]))
    for cam in open_sequence(truth["drive"]).cameras:
        rel = np.linalg.inv(cam.poses[0]) @ cam.poses[1]
        np.testing.assert_allclose(rel[:3, 3], [0, 0, 10], atol=1e-6)
        np.testing.assert_allclose(rel[:3, :3], np.eye(3), atol=1e-12)
