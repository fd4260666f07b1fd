"""A run's ego-motion kept in a file and given again (``calibrate --ego-motion``): the same result without the front
end, and a recording of another run never taken for this one's."""

import json
import shutil

import numpy as np
import pytest
import torch
import yaml

from ocalib.cli import main
from ocalib.frontend.recorded import EGO_MOTION_KIND
from ocalib.synth import preset

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def rig(render):
    """A 16-frame hand-held rig at 48x144 with its metric trajectory (the rig estimator runs too)."""
    return render(preset("handheld").with_overrides(frames=16, height=48, width=144, seed=1011))


def _calibrate(seq, out, ego, *extra) -> int:
    argv = ["calibrate", "--sequence", str(seq), "--metric-trajectory", str(seq / "cam0" / "poses.txt"),
            "--no-bundle-adjust", "--out", str(out), "--ego-motion", str(ego), *extra]  # fmt: skip
    return main(argv)


def _without_times(doc):
    """The result JSON without its wall-clock entries (every key naming seconds)."""
    if isinstance(doc, dict):
        return {k: _without_times(v) for k, v in doc.items() if "seconds" not in k}
    if isinstance(doc, list):
        return [_without_times(v) for v in doc]
    return doc


def test_a_recorded_run_is_given_again_without_the_front_end(rig, tmp_path, monkeypatch, capsys):
    ego = tmp_path / "ego.npz"
    assert _calibrate(rig, tmp_path / "first.json", ego) == 0
    assert ego.exists()
    import ocalib.calibnet.run as run

    def no_front_end(*args, **kwargs):
        raise AssertionError("the front end ran again")

    monkeypatch.setattr(run, "choose_frontend", no_front_end)
    monkeypatch.setattr(run, "build_frontend", no_front_end)
    assert _calibrate(rig, tmp_path / "again.json", ego) == 0
    first, again = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("first", "again"))
    assert first["settings"]["frontend_choice"]  # the choice of the default front end is kept too
    assert _without_times(again) == _without_times(first)


def test_a_recording_of_other_settings_is_made_again(rig, tmp_path, capsys):
    ego = tmp_path / "ego.npz"
    assert _calibrate(rig, tmp_path / "a.json", ego, "--frontend", "opencv") == 0
    before = ego.read_bytes()
    assert _calibrate(rig, tmp_path / "b.json", ego, "--frontend", "opencv", "--max-frames", "12") == 0
    assert "the front end runs again" in capsys.readouterr().err
    assert ego.read_bytes() != before
    assert json.loads((tmp_path / "b.json").read_text())["settings"]["frames"] == 12


@pytest.mark.parametrize("case", ["not a recording", "a header without its entries", "no folder", "read-only folder"])
def test_bad_recording_paths_are_one_line_and_exit_2(rig, tmp_path, capsys, monkeypatch, case):
    ego = tmp_path / "result.json"
    if case == "not a recording":
        ego.write_text('{"extrinsics": []}')  # e.g. a result JSON given by mistake: never overwritten
    elif case == "a header without its entries":  # of the right kind, cut short
        header = json.dumps({"kind": EGO_MOTION_KIND, "settings": {}, "fingerprint": "x"})
        with open(ego, "wb") as f:
            np.savez(f, motions=np.zeros((1, 1, 2, 4, 4)), header=np.array(header))
    elif case == "no folder":
        ego = tmp_path / "missing" / "ego.npz"
    else:  # said before the stream, not lost after it (the tests may run as root, who may write anywhere)
        monkeypatch.setattr("ocalib.calibnet.run.os.access", lambda path, mode: False)
    assert _calibrate(rig, tmp_path / "r.json", ego, "--frontend", "opencv") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(ego) in err[0]
    if case == "not a recording":
        assert ego.read_text() == '{"extrinsics": []}'


def test_a_recording_is_not_given_again_to_other_intrinsics(rig, tmp_path, capsys):
    """The same frames with another K in rig.yaml: the OpenCV front end's motions would differ, so it runs again."""
    seq = tmp_path / "seq"
    shutil.copytree(rig, seq)
    ego = tmp_path / "ego.npz"
    assert _calibrate(seq, tmp_path / "a.json", ego, "--frontend", "opencv") == 0
    config = yaml.safe_load((seq / "rig.yaml").read_text())
    config["cameras"][1]["K"][0][0] *= 1.01
    (seq / "rig.yaml").write_text(yaml.safe_dump(config))
    assert _calibrate(seq, tmp_path / "b.json", ego, "--frontend", "opencv") == 0
    assert "the front end runs again" in capsys.readouterr().err
