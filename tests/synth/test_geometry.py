"""The ground truth is geometrically exact: warping, rigidity, depth at pixel centres, non-overlap."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from ocalib.geometry import invert_pose
from ocalib.synth import camera_poses, preset
from ocalib.synth.world import PAVE, PITCH, ROAD


def backproject(depth, K, pose):
    """World points (H, W, 3) of a depth map (H, W) seen by a camera K (3, 3), pose (4, 4) float64."""
    H, W = depth.shape
    v, u = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    z = depth.double()
    cam = torch.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)
    return cam @ pose[:3, :3].T + pose[:3, 3]


def project(points, K, pose):
    """Pixel coordinates (..., 2) and z-depth (...) of world points in a camera."""
    inv = invert_pose(pose)
    cam = points @ inv[:3, :3].T + inv[:3, 3]
    z = cam[..., 2]
    uv = torch.stack([K[0, 0] * cam[..., 0] / z + K[0, 2], K[1, 1] * cam[..., 1] / z + K[1, 2]], -1)
    return uv, z


def warp_error(seq, cam, t, s):
    """Mean |I_t - warp(I_s)| over pixels of frame t with a surface that land inside frame s."""
    K = torch.as_tensor(seq.rig.cameras[cam].K)
    depth, image = seq.depth[cam, t], seq.images[cam, t]
    H, W = depth.shape
    uv, z = project(backproject(depth, K, seq.poses[cam, t]), K, seq.poses[cam, s])
    inside = (
        (depth > 0) & (z > 0) & (uv[..., 0] >= 0) & (uv[..., 0] <= W - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= H - 1)
    )
    grid = torch.stack([uv[..., 0] / (W - 1) * 2 - 1, uv[..., 1] / (H - 1) * 2 - 1], -1).float()
    warped = F.grid_sample(seq.images[cam, s][None], grid[None], align_corners=True)[0]
    err = (warped - image).abs().mean(0)
    return float(err[inside].mean()), float(inside.float().mean())


@pytest.mark.parametrize("name", ["front-rear", "handheld"])
def test_warp_with_ground_truth_is_photometrically_exact(rendered, name):
    seq = rendered(name)
    for cam in range(len(seq.rig.cameras)):
        for t in range(3):
            err, frac = warp_error(seq, cam, t, t + 2)
            assert frac > 0.3, (cam, t, frac)
            assert err <= 0.03, (name, cam, t, err)


def test_rig_is_rigid_to_1e6(rendered):
    for name in ["front-left", "handheld"]:
        poses = camera_poses(preset(name).with_overrides(frames=40))
        rel = np.linalg.inv(poses[0]) @ poses[1]
        assert np.abs(rel - rel[0]).max() < 1e-6
        assert np.abs(rel[0] - preset(name).cameras[1].T_cam0_cam()).max() < 1e-9


@pytest.mark.parametrize("size", [{}, {"height": 63, "width": 207}])  # an odd width: KITTI's 1241, for one
def test_depth_is_exact_at_pixel_centres_on_the_ground(rendered, size):
    seq = rendered("stereo", frames=1, **size)
    K = torch.as_tensor(seq.rig.cameras[0].K)
    pose = seq.poses[0, 0]
    H, W = seq.depth.shape[-2:]
    v, u = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    ray = torch.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], torch.ones_like(u)], -1) @ pose[:3, :3].T
    ground_z = -pose[2, 3] / ray[..., 2]  # z-depth where the centre ray meets the plane z = 0
    pts = backproject(seq.depth[0, 0], K, pose)
    on_ground = (seq.depth[0, 0] > 0) & (pts[..., 2].abs() < 1e-3)
    assert on_ground.float().mean() > 0.1
    rel = ((seq.depth[0, 0].double() - ground_z).abs() / ground_z)[on_ground]
    assert (rel < 1e-4).float().mean() > 0.99  # float32 rays; the rest are kerb faces within 1 mm of z = 0


def overlap(seq, t):
    """Fraction of camera 1's pixels with a surface whose 3D point projects into camera 0, in front of it."""
    K0, K1 = (torch.as_tensor(c.K) for c in seq.rig.cameras[:2])
    H, W = seq.depth.shape[-2:]
    d1 = seq.depth[1, t]
    uv, z = project(backproject(d1, K1, seq.poses[1, t]), K0, seq.poses[0, t])
    seen = (z > 0) & (uv[..., 0] >= -0.5) & (uv[..., 0] <= W - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= H - 0.5)
    return float((seen & (d1 > 0)).sum() / (d1 > 0).sum())


@pytest.mark.parametrize("name", ["front-rear", "front-left", "handheld"])
def test_non_overlapping_presets_do_not_overlap(rendered, name):
    seq = rendered(name)
    assert max(overlap(seq, t) for t in range(seq.depth.shape[1])) < 0.05


def test_stereo_overlaps(rendered):
    assert overlap(rendered("stereo"), 0) > 0.6


@pytest.mark.parametrize("kind", ["drive", "handheld", "lds"])
def test_trajectories_stay_on_the_road(kind):
    from ocalib.synth.trajectory import trajectory

    for seed in range(3):
        p = trajectory(kind, 400, 10.0, seed)[:, :3, 3]
        off = np.abs((p[:, :2] + PITCH / 2) % PITCH - PITCH / 2)  # distance to the nearest centrelines
        near_crossing = (off.max(1) < ROAD + PAVE + 1) & (off.min(1) < ROAD - 1)  # no parked cars there
        assert ((off.min(1) <= ROAD - 2.1) | near_crossing | (off.max(1) < ROAD)).all()
        assert ((p[:, 2] >= 0.5) & (p[:, 2] <= 3.0)).all()
        step = np.linalg.norm(np.diff(p, axis=0), axis=1)
        assert step.max() < 2.5 and step.mean() > 0.05


@pytest.mark.parametrize("name", ["front-rear", "handheld"])
def test_a_longer_sequence_starts_like_a_shorter_one(name):
    short = camera_poses(preset(name).with_overrides(frames=20))
    long = camera_poses(preset(name).with_overrides(frames=300))
    assert np.abs(long[:, :20] - short).max() < 1e-9


def test_lds_trajectory_excites_all_rotation_axes():
    from ocalib.synth.trajectory import trajectory

    R = trajectory("lds", 200, 10.0, 0)[:, :3, :3]
    rel = np.einsum("nji,njk->nik", R[:-1], R[1:])  # camera-frame rotation between frames
    axis = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], 1)
    assert (np.abs(axis).mean(0) > 0.1 * np.abs(axis).mean()).all()
