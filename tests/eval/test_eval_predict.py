"""``ocalib predict`` and ``ocalib evaluate`` end to end on a tiny rendered sequence with a randomly initialised
tiny model; the prediction loop against direct model calls; the metric path fed with the ground truth."""

import json
import shutil

import cv2
import numpy as np
import pytest
import torch

from ocalib.cli import main
from ocalib.data.image_io import read_depth
from ocalib.data.layout import open_sequence
from ocalib.data.model_view import model_view
from ocalib.errors import InputError
from ocalib.eval.evaluate import evaluate_stream
from ocalib.geometry.se3 import chain_motions, invert
from ocalib.inference.predict import FramePrediction, PredictOptions, predict_frames
from ocalib.io.poses import read_kitti
from ocalib.models import EgoMotionModel, load_model, save_model
from ocalib.synth.presets import preset

FRAMES, H, W = 8, 64, 208  # the rendered sequence
MH, MW = 96, 312  # the model's resolution: 1.5x the images' (K and depth go through the resize)


@pytest.fixture(scope="module")
def seq(render):
    torch.set_num_threads(1)
    return render(preset("front-rear").with_overrides(frames=FRAMES, height=H, width=W, seed=11))


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    torch.manual_seed(0)
    return save_model(EgoMotionModel("small", MH, MW), tmp_path_factory.mktemp("model") / "tiny.pt", {"test": True})


def test_predict_writes_depth_and_chained_kitti_poses(seq, ckpt, tmp_path):
    out = tmp_path / "pred"
    assert (
        main(
            [
                "predict",
                "--sequence",
                str(seq),
                "--out",
                str(out),
                "--checkpoint",
                str(ckpt),
                "--batch-size",
                "3",
                "--workers",
                "0",
            ]
        )
        == 0
    )
    model = load_model(ckpt)
    sequence = open_sequence(seq)
    for cam in sequence.cameras:
        folder = out / cam.name
        depth = sorted((folder / "depth").glob("*.npy"))
        assert [p.name for p in depth] == [f"{t:06d}.npy" for t in range(FRAMES)]
        d = np.load(depth[3])
        assert d.dtype == np.float32 and d.shape == (MH, MW) and (d > 0).all()
        rows = [line.split() for line in (folder / "poses.txt").read_text().splitlines()]
        assert len(rows) == FRAMES and all(len(r) == 12 for r in rows)
        P = read_kitti(folder / "poses.txt")
        np.testing.assert_allclose(P[0], np.eye(4), atol=1e-12)
        # independent reference: the model called directly on each resized pair, chained by hand
        images = [resized(p) for p in cam.images]
        with torch.no_grad():
            expected = np.eye(4)
            for t in range(1, FRAMES):
                expected = expected @ model.pose(images[t - 1][None], images[t][None])[0].double().numpy()
                np.testing.assert_allclose(P[t], expected, atol=1e-5)
            np.testing.assert_allclose(d, model.depth(images[3][None])[0, 0].numpy(), rtol=1e-4)
        K = np.loadtxt(folder / "K.txt")  # 1.5x resolution: 1.5 fx, cx' = 1.5 (cx + 0.5) - 0.5
        np.testing.assert_allclose(K[0], [1.5 * cam.K[0, 0], 0, 1.5 * (cam.K[0, 2] + 0.5) - 0.5], rtol=1e-9)


def resized(path) -> torch.Tensor:
    """An image file -> (3, MH, MW) in [0, 1], resized with OpenCV (the sequence needs no crop)."""
    image = cv2.resize(cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB), (MW, MH), interpolation=cv2.INTER_LINEAR)
    return torch.from_numpy(image).permute(2, 0, 1).float() / 255


def test_predict_flip_writes_the_flip_averaged_depth(seq, ckpt, tmp_path):
    out = tmp_path / "pred"
    assert (
        main(
            [
                "predict",
                "--sequence",
                str(seq),
                "--out",
                str(out),
                "--checkpoint",
                str(ckpt),
                "--flip",
                "--cameras",
                "rear",
                "--workers",
                "0",
            ]
        )
        == 0
    )
    model, image = load_model(ckpt), resized(open_sequence(seq, ["rear"]).cameras[0].images[2])[None]
    d = np.load(out / "rear" / "depth" / "000002.npy")
    with torch.no_grad():
        np.testing.assert_allclose(d, model.depth(image, flip=True)[0, 0].numpy(), rtol=1e-4)
        assert not np.allclose(d, model.depth(image)[0, 0].numpy(), rtol=1e-3)


def test_batching_does_not_change_the_predictions(seq, ckpt):
    model, sequence = load_model(ckpt), open_sequence(seq)
    runs = [
        list(predict_frames(model, sequence, options=PredictOptions(batch_size=b, depth=b == 1)))
        for b in (1, 3, FRAMES)
    ]
    for frames in runs:
        assert [f.frame for f in frames] == list(range(FRAMES))
        np.testing.assert_array_equal(frames[0].motion, np.tile(np.eye(4), (2, 1, 1)))
    for other in runs[1:]:
        np.testing.assert_allclose(
            np.stack([f.motion for f in other]), np.stack([f.motion for f in runs[0]]), atol=1e-5
        )
        assert other[0].depth is None
    assert runs[0][0].depth.shape == (2, MH, MW)


def test_evaluate_end_to_end(seq, ckpt, tmp_path):
    out = tmp_path / "metrics.json"
    assert (
        main(
            [
                "evaluate",
                "--sequence",
                str(seq),
                "--out",
                str(out),
                "--checkpoint",
                str(ckpt),
                "--workers",
                "0",
                "--plots",
                str(tmp_path / "plots"),
                "--rpe-delta",
                "2",
            ]
        )
        == 0
    )
    doc = json.loads(out.read_text())
    assert doc["align"] is False and doc["flip"] is False
    assert doc["frames"] == FRAMES and doc["model"] == {"size": "small", "height": MH, "width": MW}
    assert set(doc["cameras"]) == {"front", "rear"} and doc["warnings"] == []
    for name, cam in doc["cameras"].items():
        assert set(cam["depth"]) >= {"abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3", "images"}
        assert cam["depth"]["images"] == FRAMES and 0 < cam["depth"]["abs_rel"] < 10
        assert set(cam["pose"]) >= {
            "sfmlearner_5frame_snippet_ate",
            "ate_rmse",
            "rpe_trans_rmse",
            "rpe_rot_rmse_deg",
            "rotation_error_deg_median",
            "direction_error_deg_median",
            "scale_ratio_cv",
        }
        assert cam["pose"]["rpe_delta"] == 2 and cam["pose"]["moving_frames"] == FRAMES - 1
        predicted = read_kitti(cam["files"]["predicted"])
        assert predicted.shape == (FRAMES, 4, 4)
        assert read_kitti(cam["files"]["sim3_aligned"]).shape == (FRAMES, 4, 4)
        assert (tmp_path / "plots" / f"{name}.png").stat().st_size > 10_000


def test_perfect_predictor_has_zero_error(seq):
    """Ground-truth motions and depth (at 1/3 of the true scale) through the metric path: every error ~0."""
    sequence = open_sequence(seq)
    views = [model_view(cam, H, W) for cam in sequence.cameras]
    truth = [invert(cam.poses[:-1]) @ cam.poses[1:] for cam in sequence.cameras]
    frames = []
    for t in range(FRAMES):
        motion = np.stack([np.eye(4) if t == 0 else m[t - 1] for m in truth])
        motion[:, :3, 3] /= 3
        depth = np.stack([read_depth(cam.depth[t], cam.depth_scale)[0].numpy() / 3 for cam in sequence.cameras])
        frames.append(FramePrediction(t, motion, depth))
    results = evaluate_stream(sequence, frames, views)
    for r in results:
        assert r.depth["abs_rel"] < 1e-6 and r.depth["rmse"] < 1e-4 and r.depth["a1"] == 1
        for key in (
            "sfmlearner_5frame_snippet_ate",
            "ate_rmse",
            "rpe_trans_rmse",
            "rpe_rot_rmse_deg",
            "rotation_error_deg_median",
            "direction_error_deg_median",
            "scale_ratio_cv",
        ):
            assert r.pose[key] == pytest.approx(0, abs=1e-5), key
        assert r.pose["scale_ratio_median"] == pytest.approx(1 / 3)


def test_chain_composes_motions():
    motions = np.tile(np.eye(4), (3, 1, 1))
    motions[1:, :3, 3] = [1.0, 0, 0]
    motions[2, :3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    P = chain_motions(motions[1:])
    np.testing.assert_allclose(P[2], motions[1] @ motions[2])
    np.testing.assert_allclose(P[0], np.eye(4))


# --- bad input -----------------------------------------------------------------------------------------


def run_error(argv, capsys) -> str:
    assert main(argv) == 2
    return capsys.readouterr().err


def test_missing_and_foreign_checkpoints(seq, tmp_path, capsys):
    err = run_error(
        ["predict", "--sequence", str(seq), "--out", str(tmp_path / "o"), "--checkpoint", str(tmp_path / "nope.pt")],
        capsys,
    )
    assert "nope.pt" in err and "no such checkpoint" in err
    torch.save({"kind": "something-else", "weights": torch.zeros(3)}, tmp_path / "other.pt")
    err = run_error(
        [
            "evaluate",
            "--sequence",
            str(seq),
            "--out",
            str(tmp_path / "m.json"),
            "--checkpoint",
            str(tmp_path / "other.pt"),
        ],
        capsys,
    )
    assert "other.pt" in err and "another kind" in err


def test_static_sequence_is_refused(seq, ckpt, tmp_path, capsys):
    static = tmp_path / "static"
    shutil.copytree(seq, static)
    for cam in ("front", "rear"):
        images = sorted((static / cam / "images").glob("*.png"))
        for p in images[1:]:
            shutil.copy(images[0], p)
    err = run_error(
        ["predict", "--sequence", str(static), "--out", str(tmp_path / "o"), "--checkpoint", str(ckpt)], capsys
    )
    assert "no motion" in err and "front" in err
    assert not (tmp_path / "o").exists()


def test_images_too_small_for_the_model(ckpt, tmp_path, capsys):
    folder = tmp_path / "tiny"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for t in range(3):
        cv2.imwrite(str(folder / f"{t:06d}.png"), rng.integers(0, 255, (6, 20, 3), dtype=np.uint8))
    np.savetxt(folder / "K.txt", [[10, 0, 9.5], [0, 10, 2.5], [0, 0, 1]])
    err = run_error(
        ["predict", "--sequence", str(folder), "--out", str(tmp_path / "o"), "--checkpoint", str(ckpt)], capsys
    )
    assert "6x20" in err and "too small" in err


def test_evaluate_needs_ground_truth(seq, ckpt, tmp_path, capsys):
    folder = tmp_path / "folder"
    folder.mkdir()
    for p in sorted((seq / "front" / "images").glob("*.png")):
        shutil.copy(p, folder / p.name)
    np.savetxt(folder / "K.txt", open_sequence(seq).cameras[0].K)
    err = run_error(
        ["evaluate", "--sequence", str(folder), "--out", str(tmp_path / "m.json"), "--checkpoint", str(ckpt)], capsys
    )
    assert "no ground-truth depth maps and no ground-truth poses" in err
    shutil.copy(seq / "front" / "poses.txt", folder / "poses.txt")  # poses only: evaluated, and said so
    assert (
        main(
            [
                "evaluate",
                "--sequence",
                str(folder),
                "--out",
                str(tmp_path / "m.json"),
                "--checkpoint",
                str(ckpt),
                "--workers",
                "0",
            ]
        )
        == 0
    )
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["cameras"]["cam0"]["depth"] is None and doc["cameras"]["cam0"]["pose"]["frames"] == FRAMES
    assert "no ground-truth depth" in capsys.readouterr().err


def test_model_view_crops_to_the_model_aspect():
    """A 4:3 camera seen by a 1:3.25 model: centre crop of full width, K moved and scaled so that a 3-D point
    projects where the crop-and-resize takes its pixel."""
    from ocalib.data.sequence import Camera

    K = np.array([[500.0, 0, 319.5], [0, 500, 239.5], [0, 0, 1]])
    view = model_view(Camera("c", [], K, (480, 640)), MH, MW)
    x0, y0, w, h = view.crop
    assert (x0, w) == (0, 640) and h == round(640 / (MW / MH)) and y0 == (480 - h) // 2
    X = np.array([0.7, -0.4, 3.0])
    u = K @ X / X[2]
    s = np.array([MW / w, MH / h])
    expected = (u[:2] - [x0, y0] + 0.5) * s - 0.5
    np.testing.assert_allclose((view.K @ X / X[2])[:2], expected, rtol=1e-12)
    with pytest.raises(InputError, match="too small"):
        model_view(Camera("c", [], K, (480, 640)), 4 * 200, 4 * 650)


def test_an_image_of_another_size_is_named(seq, ckpt, tmp_path, capsys):
    broken = tmp_path / "broken"
    shutil.copytree(seq, broken)
    bad = broken / "rear" / "images" / "000004.png"
    cv2.imwrite(str(bad), np.zeros((H // 2, W // 2, 3), np.uint8))
    err = run_error(
        [
            "predict",
            "--sequence",
            str(broken),
            "--out",
            str(tmp_path / "o"),
            "--checkpoint",
            str(ckpt),
            "--workers",
            "0",
            "--no-depth",
        ],
        capsys,
    )
    assert "000004.png" in err and f"expected {H}x{W}" in err


def test_predict_frames_on_device(seq, ckpt, device):
    model, sequence = load_model(ckpt), open_sequence(seq)
    ref = list(predict_frames(model, sequence, options=PredictOptions(batch_size=4)))
    out = list(predict_frames(model, sequence, device=device, options=PredictOptions(batch_size=4)))
    np.testing.assert_allclose(np.stack([f.motion for f in out]), np.stack([f.motion for f in ref]), atol=1e-4)
    np.testing.assert_allclose(np.stack([f.depth for f in out]), np.stack([f.depth for f in ref]), rtol=1e-3)


@pytest.mark.parametrize("depth", [False, True])
def test_align_in_predict_is_the_stream_alignment(seq, depth):
    """``align``: each motion is the network's T_{t-1,t} aligned on the depth of frame t-1, frame after frame with
    the previous aligned motion as a prior, whatever the batching (frame 3 pairs with the previous batch's last
    frame), with or without the depth output (which shares the maps). The shipped checkpoint: an untrained
    network's corrections exceed the accepted rotation."""
    from ocalib.data.model_view import FrameImages
    from ocalib.frontend.align import StreamAligner
    from ocalib.geometry.pose import invert_pose

    model, sequence = load_model(None), open_sequence(seq)
    predictions = list(predict_frames(model, sequence, options=PredictOptions(batch_size=3, depth=depth, align=True)))
    frames = [f.motion for f in predictions]
    views = [model_view(c, model.height, model.width) for c in sequence.cameras]
    images = FrameImages(sequence, views)
    K = torch.from_numpy(np.stack([v.K for v in views])).float()
    reference = StreamAligner(len(sequence.cameras))
    for t in range(1, 5):
        with torch.no_grad():
            previous, current = images[t - 1], images[t]
            T = model.pose(previous, current)
            expected, accepted = reference(previous, current, model.depth(previous), K, invert_pose(T))
            assert accepted.any()
            if depth:
                np.testing.assert_allclose(predictions[t].depth, model.depth(current)[:, 0].numpy(), rtol=1e-4)
        np.testing.assert_allclose(frames[t], invert_pose(expected).double().numpy(), atol=1e-4)
        assert not np.allclose(frames[t], T.double().numpy(), atol=1e-4)  # the alignment changed the motion
