"""``ocalib calibrate`` end to end on sequences the tests render or write, and its clear errors."""

import json
import shutil

import cv2
import numpy as np
import pytest
import torch

from ocalib.cli import main
from ocalib.eval.pose_metrics import congruence_residual
from ocalib.frontend import FRONTENDS
from ocalib.io.poses import read_kitti
from ocalib.models import EgoMotionModel, save_model
from ocalib.synth import preset, render_sequence

torch.set_num_threads(1)  # tiny tensors: threads only add hand-over cost on a busy 2-core machine


@pytest.fixture(scope="module")
def tiny(tmp_path_factory, render):
    """A 12-frame handheld rig at 32x96 and an untrained model at that size."""
    root = tmp_path_factory.mktemp("calibrate")
    seq = render(preset("handheld").with_overrides(frames=12, height=32, width=96, seed=1003))
    torch.manual_seed(0)
    model = save_model(EgoMotionModel("small", height=32, width=96), root / "model.pt")
    return root, seq, model


def test_calibrate_writes_json_trace_plot_and_errors(tiny, tmp_path, capsys):
    root, seq, model = tiny
    out = tmp_path / "r.json"
    rc = main(
        [
            "calibrate",
            "--sequence",
            str(seq),
            "--checkpoint",
            str(model),
            "--out",
            str(out),
            "--trace",
            str(tmp_path / "t.csv"),
            "--plot",
            str(tmp_path / "p.png"),
            "--tensorboard",
            str(tmp_path / "tb"),
            "--trajectories",
            str(tmp_path / "traj"),
        ]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["reference"] == "cam0" and [e["camera"] for e in doc["extrinsics"]] == ["cam1"]
    assert doc["settings"]["refine"] == "unobservable"  # the image front ends' default
    e = doc["extrinsics"][0]
    R = np.array(e["rotation"])
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert e["frames_used"] + e["frames_rejected"] <= 12
    assert set(doc["ground_truth_errors"][0]) >= {
        "rotation_error_deg",
        "translation_direction_error_deg",
        "translation_error_rel_baseline",
        "scale_true",
        "scale_wander",
        "lever_arm_signal",
    }
    rows = np.loadtxt(tmp_path / "t.csv", delimiter=",", skiprows=1)
    assert rows.shape[0] == 12 and (tmp_path / "p.png").stat().st_size > 0
    assert any((tmp_path / "tb").iterdir())
    assert (tmp_path / "traj" / "cam1.txt").read_text().count("\n") == 12
    assert "errors against the ground truth" in capsys.readouterr().out


def test_calibrate_with_alignment(tiny, tmp_path):
    """``--align`` end to end: recorded in the settings with the number of accepted corrections per camera."""
    root, seq, model = tiny
    out = tmp_path / "r.json"
    assert main(["calibrate", "--sequence", str(seq), "--checkpoint", str(model), "--out", str(out), "--align"]) == 0
    doc = json.loads(out.read_text())
    assert doc["settings"]["align"] is True
    assert set(doc["settings"]["aligned_frames"]) == {"cam0", "cam1"}
    counts = doc["settings"]["aligned_frames"]
    assert all(0 <= n <= 11 for n in counts.values())
    for name, n in counts.items():  # a camera aligned on fewer than half its frames is reported
        assert any(w.startswith(f"{name}: the photometric alignment kept") for w in doc["warnings"]) == (n < 5.5)
    assert np.isfinite(doc["extrinsics"][0]["rotation"]).all()


def test_ground_truth_errors_are_zero_for_a_perfect_front_end(tiny):
    """calibration_metrics.extrinsic_errors on the true extrinsics as the estimate and the true trajectories: zero errors,
    metric scale 1 (an independent check of the error conventions)."""
    from ocalib.calib.drivers.online import OnlineCalibrator
    from ocalib.data import open_sequence
    from ocalib.eval.calibration_metrics import extrinsic_errors

    _, seq, _ = tiny
    sequence = open_sequence(seq)
    truth = np.stack([c.poses for c in sequence.cameras], 1)
    T = np.stack([c.T_cam0_cam for c in sequence.cameras])
    head = OnlineCalibrator(2)
    front_end = np.linalg.inv(truth[:1]) @ truth
    front_end[..., :3, 3] *= 2.5  # a front end in units of 1/2.5 m
    for p in torch.from_numpy(front_end):
        est = head(p)
    (err,) = extrinsic_errors(est, T, front_end, truth)
    assert err["rotation_error_deg"] < 0.05 and err["translation_direction_error_deg"] < 0.5
    assert err["metric_scale"] == pytest.approx(1 / 2.5, rel=1e-6)
    assert err["translation_error_rel_baseline"] < 0.01 and err["scale_true"] == pytest.approx(1.0, rel=1e-6)
    np.testing.assert_allclose(err["rotation_gain_reference"] + err["rotation_gain"], 1.0, atol=1e-9)
    # a front end that reports half the rotation of camera 1 about its z axis
    from ocalib.eval.pose_metrics import frame_motions
    from ocalib.geometry.se3 import so3_log

    steps = frame_motions(front_end[:, 1])
    rv = so3_log(steps[:, :3, :3]) * [1.0, 1.0, 0.5]
    halved = front_end.copy()
    for t, (step, r) in enumerate(zip(steps, rv)):
        step[:3, :3] = cv2.Rodrigues(r)[0]
        halved[t + 1, 1] = halved[t, 1] @ step
    (err,) = extrinsic_errors(est, T, halved, truth)
    assert err["rotation_gain"][2] == pytest.approx(0.5, abs=1e-9)
    np.testing.assert_allclose(err["rotation_gain"][:2], 1.0, atol=1e-9)


@pytest.mark.parametrize(
    "case, message",
    [
        ("unknown camera", "no camera 'cam7'"),
        ("too short", "too short to calibrate"),
        ("unequal counts", "frame is missing"),
        ("wrong checkpoint", "not an ocalib ego-motion model"),
        ("corrupt frame", "000007.png: cannot read the image"),
        ("align with opencv", "align refines the pose network's motions"),
        ("rig-align without align", "rig-align re-aligns the photometrically aligned motions"),
    ],
)
def test_clear_errors(tiny, tmp_path, capsys, case, message):
    root, seq, model = tiny
    args = ["calibrate", "--sequence", str(seq), "--checkpoint", str(model)]
    if case == "unknown camera":
        args += ["--cameras", "cam0", "cam7"]
    elif case == "too short":
        args += ["--max-frames", "5"]
    elif case == "unequal counts":
        broken = tmp_path / "seq"
        shutil.copytree(seq, broken)
        next(iter(sorted((broken / "cam1" / "images").iterdir()))).unlink()
        args[2] = str(broken)
    elif case == "align with opencv":
        args += ["--frontend", "opencv", "--align"]
    elif case == "rig-align without align":
        args += ["--no-align", "--rig-align"]
    elif case == "corrupt frame":  # read in a DataLoader worker: still one line naming the file
        broken = tmp_path / "seq"
        shutil.copytree(seq, broken)
        (broken / "cam1" / "images" / "000007.png").write_bytes(b"not a png")
        args[2] = str(broken)
    else:
        torch.save({"weights": torch.zeros(3)}, tmp_path / "other.pt")
        args[4] = str(tmp_path / "other.pt")
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


def test_demo_prints_the_estimate_beside_the_truth_and_its_warnings(tmp_path, capsys):
    """``ocalib demo`` (the README's main job) on 12 frames with the shipped checkpoint: its files, and its reported
    rotation error equals the one computed here from result.json and the rendered rig's true extrinsic."""
    from ocalib.data.layout import open_sequence
    from ocalib.geometry.se3 import rotation_angle_deg

    out = tmp_path / "demo"
    assert main(["demo", "--frames", "12", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert {p.name for p in out.iterdir()} >= {"sequence", "result.json", "trace.csv", "trace.png"}
    doc = json.loads((out / "result.json").read_text())
    truth = open_sequence(out / "sequence").cameras[1].T_cam0_cam
    R = np.array(doc["extrinsics"][0]["rotation"])
    angle = float(rotation_angle_deg(truth[:3, :3].T @ R))
    assert doc["ground_truth_errors"][0]["rotation_error_deg"] == pytest.approx(angle, abs=1e-6)
    assert "errors against the ground truth" in captured.out and f"rotation {angle:.3f} deg" in captured.out
    # the handheld preset's camera 1 is turned 120 deg about y: its roll and yaw read +180, never -180
    assert "truth 120.00 deg about (+0.000, +1.000, +0.000); roll, pitch, yaw +180.0, +60.0, +180.0 deg" in captured.out
    assert [line[len("warning: ") :] for line in captured.err.splitlines() if line.startswith("warning: ")] == doc[
        "warnings"
    ]


@pytest.mark.parametrize("frontend", ["network", "opencv"])
def test_planar_motion_with_the_network_advises_the_opencv_front_end(frontend):
    """A car's drive is flagged planar by the head; the network front end then gets the measured advice (OpenCV VO's
    rotation was lower on five of six held-out cars), the OpenCV front end and non-planar
    motion do not."""
    from ocalib.calib.drivers.online import OnlineCalibrator
    from ocalib.frontend.network import PLANAR_ADVICE, NetworkFrontEnd
    from ocalib.frontend.opencv import OpenCVFrontEnd
    from ocalib.sim.trajectory import car_trajectory, lds_trajectory, random_rig, rig_trajectories

    if frontend == "network":
        front_end = NetworkFrontEnd(EgoMotionModel("small", height=32, width=64))
    else:
        front_end = OpenCVFrontEnd(np.eye(3)[None].repeat(2, 0))
    g = torch.Generator().manual_seed(0)
    X = random_rig(g)[None]
    advice = {}
    for name, cam0 in (("car", car_trajectory(120, g)), ("handheld", lds_trajectory(120, g))):
        head = OnlineCalibrator(2)
        for poses in rig_trajectories(cam0, X):
            estimate = head(poses[None])
        advice[name] = (bool(estimate.planar_motion[0, 0]), front_end.report(["front", "left"], 120, estimate)[1])
    assert advice["car"][0] and not advice["handheld"][0]
    assert advice["car"][1] == ([f"left: {PLANAR_ADVICE}"] if frontend == "network" else [])
    assert advice["handheld"][1] == []


def test_a_surround_rig_is_calibrated_camera_by_camera_without_a_nan(tmp_path, capsys):
    """The four-camera surround preset (a straight stretch: every camera's translation unobservable) through
    ``calibrate``: three extrinsics against the front camera, each with its errors, and no NaN printed."""
    seq = render_sequence(
        preset("surround").with_overrides(frames=12, height=32, width=96, seed=1003), tmp_path / "seq", progress=False
    )
    torch.manual_seed(0)
    model = save_model(EgoMotionModel("small", height=32, width=96), tmp_path / "model.pt")
    out = tmp_path / "r.json"
    assert main(["calibrate", "--sequence", str(seq), "--checkpoint", str(model), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["reference"] == "front" and [e["camera"] for e in doc["extrinsics"]] == ["left", "right", "rear"]
    assert len(doc["ground_truth_errors"]) == 3
    printed = capsys.readouterr()
    assert "nan" not in (printed.out + printed.err).lower()


def test_the_default_front_end_is_chosen_by_the_rigs_rotation_angles(tiny, tmp_path, capsys):
    """``--frontend auto`` (the default): every registered front end tried, each one's congruence residual that of
    its own trajectories (written by a run with that front end), the smallest kept and said; a network option
    given makes it the network."""
    root, seq, model = tiny
    out = tmp_path / "auto.json"
    assert main(["calibrate", "--sequence", str(seq), "--no-bundle-adjust", "--out", str(out)]) == 0
    settings = json.loads(out.read_text())["settings"]
    tried = settings["frontend_choice"]["congruence_residual"]
    assert set(tried) == set(FRONTENDS) and settings["frontend"] == min(tried, key=tried.get)
    assert f"front end: {settings['frontend']}, chosen on the first 12 frames" in capsys.readouterr().out
    traj = tmp_path / "traj"
    args = ["--sequence", str(seq), "--no-bundle-adjust", "--frontend", "opencv", "--trajectories", str(traj)]
    assert main(["calibrate", *args]) == 0
    poses = np.stack([read_kitti(traj / f"{name}.txt") for name in ("cam0", "cam1")], 1)
    assert tried["opencv"] == pytest.approx(congruence_residual(poses), rel=1e-9)
    out = tmp_path / "net.json"
    assert main(["calibrate", "--sequence", str(seq), "--checkpoint", str(model), "--out", str(out)]) == 0
    settings = json.loads(out.read_text())["settings"]
    assert settings["frontend"] == "network" and "frontend_choice" not in settings


@pytest.mark.parametrize("chosen", FRONTENDS)
def test_the_chosen_front_end_streams_on_from_its_trial(tiny, tmp_path, monkeypatch, chosen):
    """``auto`` keeps the chosen front end's motions over the frames it was tried on and runs it on from there (each
    frame computed once; the network, whose motions follow the head, runs again): the trajectories and the result
    are those of a run with that front end named."""
    monkeypatch.setattr("ocalib.calibnet.run.AUTO_FRAMES", 5)  # tried on 5 of the 12 frames, 7 streamed on
    monkeypatch.setattr("ocalib.calibnet.run.FRONTENDS", {chosen: FRONTENDS[chosen]})  # the one tried
    _, seq, _ = tiny
    runs = {}
    for name, frontend in (("auto", []), ("named", None)):
        out, traj = tmp_path / f"{name}.json", tmp_path / name
        args = ["calibrate", "--sequence", str(seq), "--no-bundle-adjust", "--out", str(out)]
        args += ["--trajectories", str(traj)]
        if frontend is None:
            frontend = ["--frontend", runs["auto"][0]["settings"]["frontend"]]
        assert main(args + frontend) == 0
        runs[name] = json.loads(out.read_text()), np.stack([read_kitti(traj / f"cam{c}.txt") for c in (0, 1)], 1)
    (auto, auto_poses), (named, named_poses) = runs["auto"], runs["named"]
    assert auto["settings"]["frontend_choice"]["frames"] == 5 and auto["settings"]["frontend"] == chosen
    np.testing.assert_array_equal(auto_poses, named_poses)
    assert auto["extrinsics"] == named["extrinsics"]
