"""Cameras on clocks of their own paired into frames, against a brute-force nearest-stamp pairing."""

from pathlib import Path

import numpy as np
import pytest

from ocalib.data.rig import ExtrinsicChange
from ocalib.data.sequence import Camera, Sequence
from ocalib.data.synchronise import own_clocks, synchronise
from ocalib.errors import InputError

K = np.diag([100.0, 100.0, 1.0])


def camera(name, times, change=None):
    n = len(times)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n)  # the frame index, to see which frame was kept
    images = [Path(f"{name}/{i:06d}.png") for i in range(n)]
    return Camera(name, images, K, (8, 8), np.eye(4), poses, times=np.asarray(times, float), change=change)


def brute_force(t0, tk, offset, tolerance):
    """For each camera-0 stamp, the nearest camera-k stamp within tolerance, one-to-one (closest kept)."""
    best = {}
    for i, t in enumerate(t0):
        j = int(np.argmin(np.abs(t - (tk + offset))))
        d = abs(t - (tk[j] + offset))
        if d <= tolerance and (j not in best or d < best[j][1]):
            best[j] = (i, d)
    return {i: j for j, (i, _) in best.items()}


@pytest.mark.parametrize("offset", [0.0, 0.3, -0.2, 0.03, 0.05, 0.0999])
def test_frames_pair_as_the_nearest_stamps(offset):
    rng = np.random.default_rng(0)
    t0 = np.arange(55) / 10.0
    tk = np.arange(55) / 10.0 + 100.0 + rng.uniform(-0.01, 0.01, 55)  # another clock, jittered
    seq = synchronise(Sequence("s", Path("s"), "rig", [camera("a", t0), camera("b", tk)]), [offset - 100.0])
    expected = brute_force(t0, tk, offset - 100.0, 0.05)
    kept = sorted(expected)
    np.testing.assert_array_equal(seq.pairing.frames[:, 0], kept)
    np.testing.assert_array_equal(seq.pairing.frames[:, 1], [expected[i] for i in kept])
    np.testing.assert_array_equal(seq.cameras[1].poses[:, 0, 3], [expected[i] for i in kept])  # poses follow
    assert [p.name for p in seq.cameras[1].images] == [f"{expected[i]:06d}.png" for i in kept]
    np.testing.assert_allclose(seq.times, t0[kept])
    residual = t0[kept] - (tk[[expected[i] for i in kept]] + offset - 100.0)
    np.testing.assert_allclose(seq.pairing.residuals[:, 1], residual, atol=1e-12)
    assert seq.pairing.camera_json(1)["unpaired_frames"] == 55 - len(kept)
    assert not own_clocks(seq) and len(seq.cameras[1]) == len(seq.cameras[0]) == len(kept)


def test_a_change_keeps_its_frame_on_camera_0s_frames():
    t = np.arange(20) / 10.0
    moved = ExtrinsicChange(10, np.diag([1.0, -1.0, -1.0, 1.0]))
    seq = synchronise(Sequence("s", Path("s"), "rig", [camera("a", t), camera("b", t, moved)]), [0.3])
    assert seq.pairing.frames[0].tolist() == [3, 0]  # camera 1's frame 0 is camera 0's frame 3
    assert seq.cameras[1].change.frame == 10  # camera 1's own frame 10
    before = synchronise(Sequence("s", Path("s"), "rig", [camera("a", t), camera("b", t, moved)]), [-1.2])
    np.testing.assert_array_equal(before.cameras[1].T_cam0_cam, moved.T_cam0_cam)  # moved before the first pair
    assert before.cameras[1].change is None


def test_no_frame_in_common_is_one_clear_error():
    t = np.arange(20) / 10.0
    with pytest.raises(InputError, match="time ranges never overlap"):
        synchronise(Sequence("s", Path("s"), "rig", [camera("a", t), camera("b", t)]), [5.0])
    seq = Sequence("s", Path("s"), "rig", [camera("a", t), camera("b", t)])
    for cam in seq.cameras:
        cam.times = None
    with pytest.raises(InputError, match="no timestamps"):
        synchronise(seq, [0.1])


def test_cameras_of_their_own_counts_and_rates_pair_around_drops_and_gaps():
    t0 = np.delete(np.arange(30) / 10.0, [5])  # 10 Hz, frame 5 dropped
    tk = np.delete(np.arange(60) / 20.0 + 0.002, np.r_[20:30])  # 20 Hz, 2 ms late, nothing from 1.0 to 1.5 s
    seq = synchronise(Sequence("s", Path("s"), "rig", [camera("a", t0), camera("b", tk)]), [0.0])
    unpartnered = (t0 > 1.05) & (t0 < 1.45)  # 1.1 .. 1.4 s: within 0.05 s of no frame of b (1.0 s pairs 0.952 s)
    np.testing.assert_allclose(seq.times, t0[~unpartnered])
    assert seq.pairing.skipped.tolist() == [0, 4] and seq.pairing.counts.tolist() == [29, 50]
    assert seq.pairing.camera_json(1) | {"pair_residual_median_s": 0, "pair_residual_max_s": 0} == {
        "time_offset": 0.0, "source": "given", "pairs": 25, "unpaired_frames": 25, "skipped_frames": 4,
        "pair_residual_median_s": 0, "pair_residual_max_s": 0,
    }  # fmt: skip
    skipped, gap = seq.pairing.warnings  # camera a's one dropped frame is no gap (2 periods); b's 11 periods are
    assert skipped == "a: 4 of its 29 frames skipped: no frame within half a frame period in every camera " \
        "(frames without a partner: b 4)"  # fmt: skip
    assert gap.startswith("b: no frame from t = 0.952000 s to 1.502000 s (0.550 s, 11.0 of its frame periods)")


def test_a_camera_without_stamps_cannot_have_a_count_of_its_own():
    t = np.arange(10) / 10.0
    short = camera("b", t[:8])
    short.times = None
    with pytest.raises(InputError, match="frame is missing"):
        Sequence("s", Path("s"), "rig", [camera("a", t), short])
    assert Sequence("s", Path("s"), "rig", [camera("a", t), camera("b", t[:8])]).common == 8  # with stamps: fine
