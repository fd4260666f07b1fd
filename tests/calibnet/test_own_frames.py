"""A rendered rig whose cameras drop frames and stamp their own: camera 0 drops one frame, camera 1 another and stamps
3 ms later in nanoseconds. The pairing skips exactly the frames without a partner, the metric trajectory is met by
time, and ``ocalib calibrate`` runs to the end."""

import json
import shutil

import numpy as np
import pytest
import torch

from ocalib.calibnet.sequence import open_calibration_sequence
from ocalib.cli import main
from ocalib.data.metric_trajectory import OWN, read_metric_trajectory
from ocalib.errors import InputError
from ocalib.io.poses import read_kitti, write_kitti, write_tum
from ocalib.synth import preset

torch.set_num_threads(1)
FRAMES = 14
DROPPED = {"cam0": 4, "cam1": 9}  # the frame each camera drops
EPOCH = 1_700_000_000  # seconds: the cameras' clocks count from 1970, as drivers' do
LATE_NS = 3_000_000  # camera 1 stamps its frames 3 ms after camera 0


def drop(folder, frame: int) -> np.ndarray:
    """Camera ``folder`` without its frame ``frame`` (image, depth, pose) -> the frames it keeps (N - 1,)."""
    (folder / "images" / f"{frame:06d}.png").unlink()
    (folder / "depth" / f"{frame:06d}.png").unlink()
    kept = np.delete(np.arange(FRAMES), frame)
    write_kitti(folder / "poses.txt", read_kitti(folder / "poses.txt")[kept])
    return kept


@pytest.fixture(scope="module")
def own_frames(render, tmp_path_factory):
    """The rig rendered at 32x96, each camera with the frames of ``DROPPED`` left out and its own ``times.txt``:
    camera 0's in seconds, camera 1's in nanoseconds, LATE_NS later."""
    rendered = render(preset("handheld").with_overrides(frames=FRAMES, height=32, width=96, seed=1003))
    seq = tmp_path_factory.mktemp("own") / "seq"
    shutil.copytree(rendered, seq)
    kept = drop(seq / "cam0", DROPPED["cam0"])
    (seq / "cam0" / "times.txt").write_text("".join(f"{EPOCH + i / 10:.6f}\n" for i in kept))
    kept = drop(seq / "cam1", DROPPED["cam1"])
    (seq / "cam1" / "times.txt").write_text("".join(f"{EPOCH * 10**9 + i * 10**8 + LATE_NS}\n" for i in kept))
    return seq


def test_the_pairing_skips_the_frames_without_a_partner_and_counts_them(own_frames):
    seq = open_calibration_sequence(own_frames)
    pairing = seq.pairing
    paired = [i for i in range(FRAMES) if i not in DROPPED.values()]  # the frames both cameras have
    assert [p.name for p in seq.cameras[0].images] == [f"{i:06d}.png" for i in paired]
    assert [p.name for p in seq.cameras[1].images] == [f"{i:06d}.png" for i in paired]
    np.testing.assert_allclose(
        pairing.residuals[:, 1], -LATE_NS * 1e-9, rtol=0, atol=1e-6
    )  # stamps in ns read as seconds
    np.testing.assert_allclose(seq.times, EPOCH + np.array(paired) / 10, rtol=0, atol=1e-6)
    assert pairing.counts.tolist() == [FRAMES - 1, FRAMES - 1]
    assert pairing.skipped.tolist() == [0, 1]  # camera 0's frame 9: camera 1 dropped it
    json = pairing.camera_json(1)
    assert (json["pairs"], json["unpaired_frames"], json["skipped_frames"]) == (FRAMES - 2, 1, 1)
    assert pairing.warnings == (f"cam0: 1 of its {FRAMES - 1} frames skipped: no frame within half a frame period in "
                                "every camera (frames without a partner: cam1 1)",)  # fmt: skip
    truth = read_kitti(own_frames / "cam1" / "poses.txt")
    np.testing.assert_array_equal(seq.cameras[1].poses, truth[[i - (i > DROPPED["cam1"]) for i in paired]])


def test_the_metric_trajectory_is_met_by_time_and_its_gap_said(own_frames, tmp_path):
    seq = open_calibration_sequence(own_frames)
    truth = read_kitti(own_frames / "cam0" / "poses.txt")  # camera 0's 13 frames
    stamps = EPOCH + np.delete(np.arange(FRAMES), DROPPED["cam0"]) / 10
    gap = (stamps > EPOCH + 0.55) & (stamps < EPOCH + 0.85)  # no pose from 0.6 to 0.8 s: more than it bridges
    write_tum(tmp_path / "metric.txt", stamps[~gap], truth[~gap])
    met, poses, warnings = read_metric_trajectory(tmp_path / "metric.txt", seq, len(seq))
    assert len(met) == len(seq) - 3 and len(poses) == len(met)
    np.testing.assert_allclose(poses, met.cameras[0].poses, atol=1e-6)
    met_at = np.r_[0:5, 8:12]  # the paired frames at 0.6, 0.7 and 0.8 s left out
    np.testing.assert_allclose(met.times, seq.times[met_at], rtol=0, atol=1e-6)
    assert met.pairing.frames.tolist() == seq.pairing.frames[met_at].tolist()
    (line,) = warnings
    assert line.startswith(f"{tmp_path / 'metric.txt'}: no pose at 3 of the {len(seq)} frames (t = ")


def test_the_sequences_own_trajectory_is_the_metric_trajectory_where_named(own_frames):
    """``--metric-trajectory sequence``: camera 0's own poses (here its poses.txt), as from the file; a frame without
    one left out and said; a sequence without poses one line naming it."""
    seq = open_calibration_sequence(own_frames)
    own, poses, warnings = read_metric_trajectory(OWN, seq, len(seq))
    _, from_file, _ = read_metric_trajectory(own_frames / "cam0" / "poses.txt", seq, len(seq))
    assert len(own) == len(seq) and warnings == []
    np.testing.assert_allclose(poses, from_file, atol=1e-12)
    seq.cameras[0].poses[5] = np.nan  # as an extract drive's frame in a gap of its OXTS packets
    own, poses, (line,) = read_metric_trajectory(OWN, seq, len(seq))
    assert len(own) == len(seq) - 1 and np.isfinite(poses).all()
    assert line.startswith(f"{own_frames}'s own trajectory: no pose at 1 of the {len(seq)} frames")
    seq.cameras[0].poses = None
    with pytest.raises(InputError, match=f"{own_frames}: --metric-trajectory sequence: the sequence has no trajectory"):
        read_metric_trajectory(OWN, seq, len(seq))


def test_calibrate_runs_to_the_end(own_frames, tmp_path):
    out = tmp_path / "r.json"
    argv = ["calibrate", "--sequence", str(own_frames), "--frontend", "opencv", "--no-bundle-adjust"]
    assert main([*argv, "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    sync = doc["synchronisation"][0]
    assert (sync["camera"], sync["pairs"], sync["skipped_frames"]) == ("cam1", FRAMES - 2, 1)
    assert any(w.startswith("cam0: 1 of its 13 frames skipped") for w in doc["warnings"]), doc["warnings"]
