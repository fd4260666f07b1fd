"""``ocalib calibrate`` on a rig whose second camera captures late on a clock of its own: the offset found from the
front end's rotations, against the renderer's truth."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from ocalib.calibnet.run import _apart, _pairing_warnings
from ocalib.calibnet.sequence import open_calibration_sequence
from ocalib.cli import main
from ocalib.synth import preset

torch.set_num_threads(1)
LATE = 0.05  # seconds: half a frame at 10 Hz


@pytest.fixture(scope="module")
def late(render):
    """A 100-frame hand-held rig at 48x160 whose camera 1 captures LATE seconds after camera 0."""
    cfg = preset("handheld").with_overrides(frames=100, height=48, width=160, seed=1003)
    cameras = [cfg.cameras[0], dataclasses.replace(cfg.cameras[1], time_offset=LATE)]
    return render(cfg.with_overrides(cameras=cameras))


def test_the_offset_is_found_to_a_tenth_of_a_frame(late, tmp_path):
    out = tmp_path / "r.json"
    argv = ["calibrate", "--sequence", str(late), "--frontend", "opencv", "--no-bundle-adjust", "--out", str(out)]
    trace = tmp_path / "t.csv"
    assert main([*argv, "--time-offset", "auto", "--trace", str(trace), "--plot", str(tmp_path / "p.png")]) == 0
    doc = json.loads(out.read_text())
    header = trace.read_text().splitlines()[0].split(",")
    residuals = np.loadtxt(trace, delimiter=",", skiprows=1)[:, header.index("pair_residual_s")]
    found = doc["extrinsics"][0]["time_offset"]
    assert abs(found - LATE) < 0.01, found  # a tenth of a frame
    sync = doc["synchronisation"][0]
    assert sync["camera"] == "cam1" and sync["source"] == "estimated" and sync["time_offset"] == found
    assert sync["true_time_offset"] == LATE  # from rig.yaml
    # every camera-1 frame i pairs with camera 0's frame i: what is left of the offset is all of it
    assert sync["pairs"] == 100 and sync["pair_residual_median_s"] == pytest.approx(found, abs=1e-9)
    np.testing.assert_allclose(residuals, -found, atol=1e-9)  # per frame in the trace: t0 - (t1 + offset)
    assert doc["time_offset_estimates"][0]["correlation"] > 0.5
    assert any(w.startswith("cam1: its frames pair with cam0's 0.0") for w in doc["warnings"]), doc["warnings"]

    given = open_calibration_sequence(late, time_offset=[0.3]).pairing  # three frames: camera 0's first three unpaired
    assert given.camera_json(1) | {"pair_residual_median_s": 0, "pair_residual_max_s": 0} == {
        "time_offset": 0.3, "source": "given", "pairs": 97, "unpaired_frames": 3, "skipped_frames": 3,
        "pair_residual_median_s": 0, "pair_residual_max_s": 0,
    }  # fmt: skip
    assert given.camera_json(1)["pair_residual_max_s"] < 1e-9
    assert _pairing_warnings(open_calibration_sequence(late, time_offset=[0.3])) == []  # whole frames: no gap left
    half = open_calibration_sequence(late, time_offset=[LATE])  # pairs half a frame apart: camera 1 is flagged
    assert list(_apart(half)) == [1] and _apart(open_calibration_sequence(late, time_offset=[0.3])) == {}
    (placed,) = _pairing_warnings(half, placed=True)  # with the on-line rig estimator, its result is the one kept
    assert (
        placed.startswith("cam1: its frames pair with cam0's 0.050 s (0.50 frames) apart") and "estimator's" in placed
    )
