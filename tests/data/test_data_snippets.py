"""Training snippets, static-frame filtering, the synchronised stream and snippet augmentation."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from data_fixtures import H, K, W, noise_image, trajectory, write_kitti_odometry, write_kitti_raw, write_png, write_rig

from ocalib.data import RigStream, SnippetAugmentation, SnippetDataset, collate_snippets, open_sequence
from ocalib.data.frame_cache import FrameCache
from ocalib.data.intrinsics import flip_pose
from ocalib.errors import InputError


def constant_frames(root, n):
    """Frame t of cam0 is the grey level 20 t, so the snippet order can be read from the pixels."""
    for t in range(n):
        write_png(root / "cam0" / "images" / f"{t:06d}.png", np.full((H, W, 3), 20 * t, np.uint8))


def test_snippet_order_resize_depth_and_poses(tmp_path):
    write_rig(tmp_path, n=6)
    constant_frames(tmp_path, 6)
    seq = open_sequence(tmp_path)
    ds = SnippetDataset([seq], offsets=[-2, 1], size=(12, 40))
    assert len(ds) == 2 * 3  # two cameras, targets 2..4
    s = ds[0]
    assert (s["sequence"], s["camera"], s["frame"]) == (tmp_path.name, "cam0", 2)
    assert s["image"].shape == (3, 3, 12, 40) and s["image"].dtype == torch.float32
    np.testing.assert_allclose(s["image"].mean((1, 2, 3)) * 255, [40, 0, 60], atol=1e-3)  # target, t-2, t+1
    np.testing.assert_allclose(s["K"], [[25, 0, 19.5], [0, 25, 5.5], [0, 0, 1]], atol=1e-5)
    np.testing.assert_allclose(s["depth"][:, 0, 0, 0], [4, 2, 5])  # metres: frame + 2
    P = trajectory(6)
    np.testing.assert_allclose(s["poses"], np.linalg.inv(P[2]) @ P[[2, 0, 3]], atol=1e-5)


def test_grey_images_are_expanded(tmp_path):
    seq = open_sequence(write_kitti_odometry(tmp_path, n=3), cameras=["image_0"])
    image = SnippetDataset([seq])[0]["image"]
    assert image.shape == (3, 3, H, W)
    assert torch.equal(image[:, 0], image[:, 1]) and torch.equal(image[:, 0], image[:, 2])


def test_static_frames_are_dropped(tmp_path):
    write_rig(tmp_path, n=7, depth=False)
    still = noise_image(3)
    for t in (2, 3, 4):  # the rig stands still over frames 2..4
        write_png(tmp_path / "cam0" / "images" / f"{t:06d}.png", still)
    seq = open_sequence(tmp_path, cameras=["cam0"])
    assert [i[2] for i in SnippetDataset([seq]).items] == [1, 2, 3, 4, 5]
    assert [i[2] for i in SnippetDataset([seq], static_threshold=0.02).items] == [1, 2, 4, 5]


def test_bad_offsets(tmp_path):
    write_rig(tmp_path, n=3)
    with pytest.raises(InputError):
        SnippetDataset([open_sequence(tmp_path)], offsets=[0, 1])


def test_collate_keeps_common_keys(tmp_path):
    write_rig(tmp_path / "a", n=3)
    write_rig(tmp_path / "b", n=3, depth=False)
    seqs = [open_sequence(tmp_path / "a"), open_sequence(tmp_path / "b")]
    seqs[1].cameras = [replace(c, poses=None) for c in seqs[1].cameras]
    ds = SnippetDataset(seqs, size=(12, 40))
    batch = collate_snippets([ds[0], ds[len(ds) - 1]])
    assert set(batch) == {"image", "K", "sequence", "camera", "frame"}
    assert batch["image"].shape == (2, 3, 3, 12, 40)


def test_rig_stream(tmp_path):
    truth = write_rig(tmp_path, n=4)
    stream = RigStream(open_sequence(tmp_path), cameras=["cam0", "cam1"], size=(12, 40))
    frames = list(stream)
    assert len(frames) == 4 and stream.cameras == ["cam0", "cam1"]
    f = frames[2]
    assert f["image"].shape == (2, 3, 12, 40) and f["depth"].shape == (2, 1, 12, 40) and f["K"].shape == (2, 3, 3)
    assert f["frame"] == 2 and f["time"] == pytest.approx(0.2)
    assert f["poses"].dtype == torch.float64
    np.testing.assert_allclose(f["poses"][0], truth["poses0"][2], atol=1e-8)
    np.testing.assert_allclose(f["poses"][1], f["poses"][0] @ f["T_cam0_cam"][1], atol=1e-8)
    np.testing.assert_allclose(f["K"][1], [[25, 0, 19.5], [0, 25, 5.5], [0, 0, 1]], atol=1e-5)


def test_kitti_raw_stream(tmp_path):
    stream = RigStream(open_sequence(write_kitti_raw(tmp_path, n=3)["drive"]), cameras=["image_02", "image_03"])
    f = stream[1]
    assert f["image"].shape == (2, 3, H, W) and "depth" not in f
    np.testing.assert_allclose(f["T_cam0_cam"][1, :3, 3], [0.54, 0, 0], atol=1e-9)
    assert f["time"] == pytest.approx(f["time"] - stream[0]["time"] + stream[0]["time"])
    assert stream[2]["time"] - stream[0]["time"] == pytest.approx(0.2072, abs=1e-6)


def test_stream_needs_a_common_size(tmp_path):
    write_rig(tmp_path, n=2, depth=False)
    seq = open_sequence(tmp_path)
    seq.cameras[1].size = (12, 40)
    for t in range(2):
        write_png(tmp_path / "cam1" / "images" / f"{t:06d}.png", noise_image(t, size=(12, 40)))
    with pytest.raises(InputError, match="different image sizes"):
        RigStream(seq)
    assert RigStream(seq, size=(12, 40))[0]["image"].shape == (2, 3, 12, 40)


# --- augmentation -----------------------------------------------------------------------------------------
def test_augmentation_is_identical_on_every_frame():
    torch.manual_seed(0)
    image = torch.rand(1, 3, 24, 80).expand(3, 3, 24, 80)
    aug = SnippetAugmentation(brightness=0.3, contrast=0.3, saturation=0.3, hue=0.1, flip_p=0.5, max_zoom=1.5)
    for _ in range(10):
        out = aug({"image": image, "K": torch.from_numpy(K).float(), "poses": torch.eye(4).expand(3, 4, 4)})
        assert out["image"].shape == image.shape
        assert not torch.allclose(out["image"][0], image[0])
        assert torch.equal(out["image"][0], out["image"][1]) and torch.equal(out["image"][0], out["image"][2])


def blob_snippet(poses, point):
    """Frames (S, 3, 48, 160) seeing a Gaussian blob at the projection of ``point`` (target frame)."""
    K_big = torch.tensor([[60.0, 0, 79.5], [0, 60, 23.5], [0, 0, 1]], dtype=torch.float64)
    v, u = torch.meshgrid(torch.arange(48.0), torch.arange(160.0), indexing="ij")
    frames = []
    for T in poses:
        uv = project(K_big, torch.linalg.inv(T) @ point)
        frames.append(torch.exp(-((u - uv[0]) ** 2 + (v - uv[1]) ** 2) / 8).expand(3, 48, 160))
    return {
        "image": torch.stack(frames),
        "K": K_big.float(),
        "poses": poses.float(),
        "depth": torch.ones(len(poses), 1, 48, 160),
    }


def project(K, X):
    x = K.double() @ X[:3].double()
    return (x[:2] / x[2]).double()


def centroid(g):
    v, u = torch.meshgrid(torch.arange(g.shape[0] * 1.0), torch.arange(g.shape[1] * 1.0), indexing="ij")
    return torch.stack([(g * u).sum(), (g * v).sum()]).double() / g.sum()


@pytest.mark.parametrize("flip_p", [0.0, 1.0])
def test_augmentation_updates_K_and_poses(flip_p):
    """After a random crop, resize and flip, every frame's blob is where the new K and poses project it."""
    torch.manual_seed(3)
    P = torch.from_numpy(trajectory(3)[[1, 0, 2]]).float()
    poses = torch.linalg.inv(P[0]) @ P  # target first
    point = torch.tensor([0.3, 0.1, 5.0, 1.0])
    aug = SnippetAugmentation(brightness=0, contrast=0, saturation=0, hue=0, flip_p=flip_p, max_zoom=1.4)
    for _ in range(3):
        out = aug(blob_snippet(poses, point))
        assert out["depth"].shape == (3, 1, 48, 160) and not torch.equal(out["K"], blob_snippet(poses, point)["K"])
        seen = flip_pose(point[None, :, None].expand(1, 4, 4))[0, :, 0] if flip_p else point  # M X
        for s in range(3):
            expected = project(out["K"].double(), torch.linalg.inv(out["poses"][s].double()) @ seen.double())
            np.testing.assert_allclose(centroid(out["image"][s, 0]), expected, atol=0.05)


def test_frame_cache_keeps_frames_up_to_its_limit():
    loads = []

    def load(n):
        loads.append(n)
        return np.full(10, n, np.uint8)  # 10 bytes

    cache = FrameCache(25)
    assert [cache(k, lambda k=k: load(k))[0] for k in (1, 2, 3, 1, 2, 3)] == [1, 2, 3, 1, 2, 3]
    assert loads == [1, 2, 3, 3]  # two fit; the third is decoded every time
    assert len(cache) == 2 and cache.nbytes == 20
    with pytest.raises(ValueError):  # a stored frame is shared by every later read: it cannot be written
        cache(1, lambda: load(1))[0] = 7


def test_cached_snippets_equal_decoded_ones(tmp_path):
    write_rig(tmp_path, n=6)
    seq = open_sequence(tmp_path)
    plain, cached = SnippetDataset([seq], size=(12, 40)), SnippetDataset([seq], size=(12, 40), cache_mb=1)
    for epoch in range(2):  # the second epoch reads every frame from the cache
        for i in range(len(plain)):
            a, b = plain[i], cached[i]
            assert torch.equal(a["image"], b["image"]) and torch.equal(a["depth"], b["depth"])
    assert len(cached.cache) == 2 * 6 * 2  # every frame of both cameras, image and depth
    assert len(plain.cache) == 0
