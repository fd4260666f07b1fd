"""``ocalib calibrate`` with the rig bundle adjustment: a stereo pair written as a KITTI odometry tree recovers its
baseline in metres, and the stage's options fail with one clear line."""

import json
import shutil

import numpy as np
import pytest
import torch

from ocalib.cli import main
from ocalib.data.layout import open_sequence
from ocalib.io.poses import write_kitti
from ocalib.synth import preset

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def stereo(tmp_path_factory, render):
    """The renderer's stereo preset (0.54 m baseline, overlapping views), 40 frames at 128x416, rewritten as a KITTI
    odometry tree: image_2 / image_3, calib.txt with P0..P3, times.txt and poses/00.txt (the left camera's)."""
    root = tmp_path_factory.mktemp("stereo")
    rendered = open_sequence(render(preset("stereo").with_overrides(frames=40, height=128, width=416, seed=1013)))
    folder = root / "dataset" / "sequences" / "00"
    for name, cam in zip(("image_2", "image_3"), rendered.cameras):
        (folder / name).mkdir(parents=True)
        for t, image in enumerate(cam.images):
            shutil.copy(image, folder / name / f"{t:06d}.png")
    K = rendered.cameras[0].K
    baseline = rendered.cameras[1].T_cam0_cam[0, 3]
    P = np.hstack([K, np.zeros((3, 1))])
    right = P.copy()
    right[0, 3] = -K[0, 0] * baseline
    (folder / "calib.txt").write_text(
        "".join(f"P{i}: {' '.join(f'{v:.12e}' for v in M.ravel())}\n" for i, M in enumerate((P, P, P, right)))
    )
    (folder / "times.txt").write_text("".join(f"{0.1 * t:.6e}\n" for t in range(len(rendered))))
    poses = rendered.cameras[0].poses
    write_kitti(root / "dataset" / "poses" / "00.txt", np.linalg.inv(poses[:1]) @ poses)
    return folder, root / "dataset" / "poses" / "00.txt", baseline


def test_stereo_kitti_tree_recovers_its_baseline(stereo, tmp_path):
    folder, poses, baseline = stereo
    out = tmp_path / "r.json"
    args = [
        "calibrate",
        "--sequence",
        str(folder),
        "--frontend",
        "opencv",
        "--cross-camera",
        "--keyframe-step",
        "2",
        "--metric-trajectory",
        str(poses),
        "--out",
        str(out),
        "--trace",
        str(tmp_path / "t.csv"),
        "--plot",
        str(tmp_path / "p.png"),
    ]
    assert main(args) == 0
    doc = json.loads(out.read_text())
    assert doc["units"] == "metres"
    e = doc["extrinsics"][0]
    assert e["source"] == "bundle_adjustment", doc["warnings"]
    np.testing.assert_allclose(e["translation"], [baseline, 0, 0], atol=0.1 * baseline)
    errors = doc["ground_truth_errors"][0]
    assert errors["rotation_error_deg"] < 0.5 and errors["translation_error_rel_baseline"] < 0.1
    assert "online_extrinsics" in doc and doc["online_extrinsics"][0]["camera"] == "image_3"
    header = (tmp_path / "t.csv").read_text().splitlines()[0].split(",")
    rows = np.loadtxt(tmp_path / "t.csv", delimiter=",", skiprows=1)
    ba = rows[:, header.index("ba_tx")]
    assert np.isnan(ba[:-1]).all() and ba[-1] == pytest.approx(e["translation"][0])  # one run, at the last frame


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--metric-trajectory", "short"], "poses for the 40 frames"),
        (["--metric-trajectory", "missing.txt"], "missing.txt"),
        (["--bundle-adjust-every", "0"], "--bundle-adjust-every must be at least 1"),
        (["--no-bundle-adjust", "--no-online-rig", "--metric-trajectory", "poses"], "drop --no-online-rig"),
    ],
)
def test_clear_errors(stereo, tmp_path, capsys, extra, message):
    folder, poses, _ = stereo
    short = tmp_path / "short.txt"
    short.write_text("".join(poses.read_text().splitlines(keepends=True)[:10]))
    extra = [
        {"short": str(short), "poses": str(poses), "missing.txt": str(tmp_path / "missing.txt")}.get(a, a)
        for a in extra
    ]
    assert main(["calibrate", "--sequence", str(folder), "--frontend", "opencv", *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
