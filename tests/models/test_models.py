"""Depth and pose networks: shapes, ranges, pose convention and initialisation; slim files and load errors."""

import cv2
import numpy as np
import pytest
import torch

import ocalib.models.io as model_io
from ocalib.errors import InputError
from ocalib.models import EgoMotionModel, disp_to_depth, load_model, motion_to_pose, save_model

H, W = 32, 96


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return EgoMotionModel("small", H, W).eval()


def test_depth_and_pose_shapes_and_ranges(model):
    image = torch.rand(2, 3, H, W)
    disps = model.disparities(image)
    assert [d.shape[-2:] for d in disps] == [(H // 2**s, W // 2**s) for s in range(4)]
    assert all(((d > 0) & (d < 1)).all() for d in disps)
    depth = model.depth(image)
    assert depth.shape == (2, 1, H, W) and (depth >= 0.1).all() and (depth <= 100).all()
    odd = model.depth(torch.rand(1, 3, 40, 100))  # any size (not a multiple of 32)
    assert odd.shape == (1, 1, 40, 100)
    T = model.pose(image, image.flip(0))
    assert T.shape == (2, 4, 4) and T.dtype == torch.float32
    torch.testing.assert_close(T[:, 3], torch.tensor([0.0, 0, 0, 1]).expand(2, 4))
    assert (T[:, :3, :3] - torch.eye(3)).abs().max() < 0.05  # small output initialisation: near the identity
    assert T[:, :3, 3].norm(dim=-1).max() < 0.05


def test_flipped_depth_is_mirror_symmetric_and_the_mean_disparity(model):
    """``depth(flip=True)``: the disparity averaged with the mirrored image's, mirrored back. It commutes with
    mirroring the image, which the plain depth of an untrained network does not."""
    image = torch.rand(2, 3, H, W)
    with torch.no_grad():
        flipped = model.depth(image, flip=True)
        mean = 0.5 * (model.disparities(image)[0] + model.disparities(image.flip(-1))[0].flip(-1))
        torch.testing.assert_close(flipped, disp_to_depth(mean, 0.1, 100.0))
        torch.testing.assert_close(model.depth(image.flip(-1), flip=True), flipped.flip(-1))
        assert not torch.allclose(model.depth(image.flip(-1)), model.depth(image).flip(-1))


def test_disp_to_depth_bounds():
    torch.testing.assert_close(disp_to_depth(torch.tensor([0.0, 1.0]), 0.1, 100.0), torch.tensor([100.0, 0.1]))


def test_motion_to_pose_is_rodrigues():
    motion = torch.tensor([[0.1, -0.2, 0.3, 1.0, 2.0, 3.0]], dtype=torch.float64)
    T = motion_to_pose(motion)
    R, _ = cv2.Rodrigues(motion[0, :3].numpy())
    np.testing.assert_allclose(T[0, :3, :3].numpy(), R, atol=1e-12)
    np.testing.assert_allclose(T[0, :3, 3].numpy(), [1, 2, 3])


def test_pose_gradients_flow_from_the_output(model):
    image = torch.rand(1, 3, H, W)
    train = EgoMotionModel("small", H, W)
    train.pose(image, image.roll(3, -1))[:, :3, 3].sum().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in train.pose_net.parameters())


def test_save_load_round_trip(model, tmp_path):
    path = save_model(model, tmp_path / "m.pt", {"steps": 3})
    assert path.stat().st_size < 20e6
    loaded = load_model(path)
    assert not loaded.training and (loaded.size, loaded.height, loaded.width) == ("small", H, W)
    image = torch.rand(2, 3, H, W)
    with torch.no_grad():
        torch.testing.assert_close(loaded.depth(image), model.depth(image), rtol=0, atol=0)
        torch.testing.assert_close(loaded.pose(image, image.flip(0)), model.pose(image, image.flip(0)), rtol=0, atol=0)
    data = torch.load(path, weights_only=True)
    assert data["kind"] == "ocalib-egomotion" and data["version"] == 1 and data["meta"] == {"steps": 3}


def test_unknown_size_is_an_input_error():
    with pytest.raises(InputError, match="huge"):
        EgoMotionModel("huge")


def test_load_errors_name_the_file(tmp_path, monkeypatch):
    with pytest.raises(InputError, match="no such checkpoint"):
        load_model(tmp_path / "missing.pt")
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a torch file")
    with pytest.raises(InputError, match=r"corrupt.pt: not a readable torch checkpoint \(a text file\)"):
        load_model(corrupt)
    corrupt.write_bytes(b"\x80\x02not a torch file\x00\xff")
    with pytest.raises(InputError, match=r"corrupt.pt: not a readable torch checkpoint \((?!a text file)"):
        load_model(corrupt)
    other = tmp_path / "other.pt"
    torch.save({"kind": "something-else", "state_dict": {}}, other)
    with pytest.raises(InputError, match="other.pt: a torch file of another kind .*something-else"):
        load_model(other)
    tensor = tmp_path / "tensor.pt"
    torch.save(torch.zeros(3), tensor)
    with pytest.raises(InputError, match="tensor.pt: a torch file holding a Tensor"):
        load_model(tensor)
    bad = tmp_path / "bad.pt"
    torch.save(
        {
            "kind": "ocalib-egomotion",
            "version": 1,
            "size": "small",
            "height": H,
            "width": W,
            "state_dict": {"x": torch.zeros(1)},
            "meta": {},
        },
        bad,
    )
    with pytest.raises(InputError, match="bad.pt: weights do not fit"):
        load_model(bad)
    monkeypatch.setattr(model_io, "DEFAULT_CHECKPOINT", tmp_path / "default.pt")
    with pytest.raises(InputError, match="default.pt: no default checkpoint.*ocalib train fit"):
        load_model(None)
