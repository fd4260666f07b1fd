import numpy as np
import pytest
import torch

from ocalib.synth import WorldTensors, make_world, preset, render_rig, render_view

# The renderer's many small ops suffer badly from intra-op threads on a busy 2-core machine.
torch.set_num_threads(1)

SIZE = dict(height=128, width=416)


def render_poses(poses: np.ndarray, K: np.ndarray, seed: int = 3, height: int = 128, width: int = 416) -> np.ndarray:
    """Render camera-to-world poses (N, 4, 4) of one camera in the street world of ``seed``:
    images (N, H, W, 3) uint8."""
    xy = poses[:, :2, 3]
    world = WorldTensors.from_world(make_world(seed, xy.min(0) - 60, xy.max(0) + 60))
    out = []
    with torch.inference_mode():
        for pose in poses:
            image, _ = render_view(world, K, pose, height, width, 2)
            out.append((image.permute(1, 2, 0).numpy() * 255 + 0.5).clip(0, 255).astype(np.uint8))
    return np.stack(out)


@pytest.fixture(scope="session")
def handheld():
    """A short handheld sequence (in memory), rendered once: images (K, N, 3, H, W), poses, K per camera."""
    return render_rig(preset("handheld").with_overrides(frames=20, seed=5, **SIZE))


@pytest.fixture(scope="session")
def street_pose():
    """Camera 0's first pose on the drive route of seed 3: in the street, looking along it."""
    from ocalib.synth import camera_poses

    return camera_poses(preset("front-left").with_overrides(frames=1, seed=3))[0, 0]
