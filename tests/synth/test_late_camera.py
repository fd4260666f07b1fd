"""A camera on a clock of its own: rendered late by its ``time_offset``, its own stamps and the truth written."""

import copy

import numpy as np
import pytest

from ocalib.data.layout import open_sequence
from ocalib.data.rig import read_rig_yaml
from ocalib.errors import InputError
from ocalib.synth import PRESETS, camera_poses, config_from_dict, render_sequence
from ocalib.synth.trajectory import trajectory

TINY = dict(frames=8, height=32, width=96)


def late(offset, frames=8, preset="handheld"):
    data = copy.deepcopy(PRESETS[preset])
    data["cameras"][1]["time_offset"] = offset
    return config_from_dict(data, preset).with_overrides(**TINY | {"frames": frames})


@pytest.mark.parametrize("kind", ["drive", "handheld", "lds"])
def test_sampling_at_frames_is_the_trajectory_and_runs_on_past_its_end(kind):
    poses = trajectory(kind, 40, 10.0, 3)
    longer = trajectory(kind, 50, 10.0, 3)
    np.testing.assert_array_equal(trajectory(kind, 40, 10.0, 3, at=np.arange(40)), poses)
    np.testing.assert_array_equal(trajectory(kind, 40, 10.0, 3, at=np.arange(40) + 6.0), longer[6:46])
    half = trajectory(kind, 40, 10.0, 3, at=np.arange(39) + 0.5)  # the position is linear between frames
    np.testing.assert_allclose(half[:, :3, 3], (poses[:-1, :3, 3] + poses[1:, :3, 3]) / 2, atol=1e-12)


def test_a_camera_late_by_whole_frames_sees_what_camera_0_sees_frames_later():
    poses = camera_poses(late(0.3))  # 3 frames at 10 Hz
    synchronised = camera_poses(late(0.0, frames=11))
    np.testing.assert_array_equal(poses[0], synchronised[0, :8])
    np.testing.assert_allclose(poses[1], synchronised[1, 3:11], atol=1e-12)


def test_the_layout_holds_the_cameras_stamps_and_the_true_offset(tmp_path):
    cfg = late(0.25)
    out = render_sequence(cfg, tmp_path / "seq", progress=False)
    rig = read_rig_yaml(out / "rig.yaml")
    assert [c.time_offset for c in rig.cameras] == [0.0, 0.25]
    seq = open_sequence(out)
    for cam in seq.cameras:
        np.testing.assert_allclose(cam.times, np.arange(8) / 10.0)  # each on its own clock, started at its frame 0
    assert seq.cameras[1].time_offset == 0.25
    synchronised = render_sequence(late(0.0), tmp_path / "sync", progress=False)
    assert not (synchronised / "cam1" / "times.txt").exists()
    assert read_rig_yaml(synchronised / "rig.yaml").cameras[1].time_offset is None


@pytest.mark.parametrize("offset", [-0.1, 2.5, float("nan")])
def test_a_time_offset_out_of_range_is_refused(offset):
    with pytest.raises(InputError, match="time_offset must be seconds in"):
        late(offset)


def test_camera_0_keeps_the_clock():
    data = copy.deepcopy(PRESETS["handheld"])
    data["cameras"][0]["time_offset"] = 0.1
    with pytest.raises(InputError, match="camera 0 .* defines the clock"):
        config_from_dict(data, "handheld")
