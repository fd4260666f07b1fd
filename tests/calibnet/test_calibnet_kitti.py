"""``ocalib calibrate`` on the KITTI odometry layout with the grey pair (images rendered by the test).

The rig drives straight (pure translation), so the rotation between the cameras is unobservable and must
be reported so, whatever the front end.
"""

import json

import cv2
import numpy as np
import torch

from ocalib.cli import main
from ocalib.io.poses import write_kitti
from ocalib.models import EgoMotionModel, save_model
from ocalib.synth import preset
from ocalib.synth.render import WorldTensors, render_view
from ocalib.synth.sequence import camera_poses, world_for

torch.set_num_threads(1)

H, W, FRAMES, BASELINE = 64, 208, 14, 0.54


def write_straight_kitti_odometry(root, frames=FRAMES):
    """A straight drive along the first heading of the front-rear preset's route, as sequences/00 + poses/00.txt."""
    cfg = preset("stereo").with_overrides(frames=3, height=H, width=W, seed=1004)
    start = camera_poses(cfg)[0, 0]
    poses = np.repeat(start[None], frames, 0)
    poses[:, :3, 3] += 0.5 * np.arange(frames)[:, None] * start[:3, 2]  # along the camera's optical axis
    K = cfg.cameras[0].K(H, W)
    right = poses @ np.array([[1, 0, 0, BASELINE], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    world = WorldTensors.from_world(world_for(cfg, np.stack([poses, right])))
    folder = root / "dataset" / "sequences" / "00"
    for name, traj in (("image_0", poses), ("image_1", right)):
        (folder / name).mkdir(parents=True)
        for t, pose in enumerate(traj):
            image, _ = render_view(world, K, pose, H, W)
            grey = (image.mean(0).numpy() * 255).round().astype(np.uint8)
            cv2.imwrite(str(folder / name / f"{t:06d}.png"), grey)
    P0 = np.hstack([K, np.zeros((3, 1))])
    P1 = P0.copy()
    P1[0, 3] = -K[0, 0] * BASELINE
    (folder / "calib.txt").write_text(
        "".join(f"P{i}: {' '.join(f'{v:.12e}' for v in P.ravel())}\n" for i, P in enumerate((P0, P1)))
    )
    (folder / "times.txt").write_text("".join(f"{0.1 * t:.6e}\n" for t in range(frames)))
    write_kitti(root / "dataset" / "poses" / "00.txt", np.linalg.inv(poses[:1]) @ poses)
    return folder


def test_kitti_odometry_grey_pair_straight_drive(tmp_path):
    seq = write_straight_kitti_odometry(tmp_path)
    model = save_model(EgoMotionModel("small", height=32, width=104), tmp_path / "model.pt")
    for frontend in ("opencv", "network"):
        out = tmp_path / f"{frontend}.json"
        args = [
            "calibrate",
            "--sequence",
            str(seq),
            "--frontend",
            frontend,
            "--out",
            str(out),
            "--trajectories",
            str(tmp_path / frontend),
        ]
        assert main(args + (["--checkpoint", str(model)] if frontend == "network" else [])) == 0
        doc = json.loads(out.read_text())
        assert doc["reference"] == "image_0" and doc["extrinsics"][0]["camera"] == "image_1"
        if frontend == "opencv":  # straight driving: the rotation between the cameras is unobservable
            obs = doc["extrinsics"][0]["observability"]
            assert not obs["rotation_observable"] and not obs["planar_motion"]
            assert any("rotation not observable" in w for w in doc["warnings"])
            # and the VO saw the straight motion: it ends ahead along the optical axis
            end = np.loadtxt(tmp_path / frontend / "image_0.txt")[-1].reshape(3, 4)[:, 3]
            assert end[2] / np.linalg.norm(end) > 0.99
