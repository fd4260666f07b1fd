import pytest
import torch

from ocalib.synth import camera_poses, preset, render_rig

# The renderer's many small ops suffer badly from intra-op threads on a busy 2-core machine.
torch.set_num_threads(1)


@pytest.fixture(scope="session")
def handheld():
    """A short handheld sequence in memory, rendered once: images (K, N, 3, H, W), poses, rig."""
    return render_rig(preset("handheld").with_overrides(frames=20, seed=5, height=128, width=416))


@pytest.fixture(scope="session")
def street_pose():
    """Camera 0's first pose on the drive route of seed 3: in the street, looking along it."""
    return camera_poses(preset("front-left").with_overrides(frames=1, seed=3))[0, 0]
