"""Bad clocks: a camera's times.txt, rig.yaml's time_offset and --time-offset, each one line and exit code 2."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from ocalib.cli import main

K = [[104.0, 0.0, 103.5], [0.0, 102.4, 31.5], [0.0, 0.0, 1.0]]


def layout(root, times=None, time_offset=None, frames=12):
    """A rig folder of empty images whose camera 'side' has its own stamps ``times`` (one a line, as written)."""
    cameras = [{"name": n, "width": 208, "height": 64, "K": K} for n in ("front", "side")]
    if time_offset is not None:
        cameras[1]["time_offset"] = time_offset
    (root / "seq").mkdir()
    (root / "seq" / "rig.yaml").write_text(yaml.safe_dump({"frame_rate": 10.0, "cameras": cameras}))
    for cam in cameras:
        (root / "seq" / cam["name"] / "images").mkdir(parents=True)
        for i in range(frames):
            (root / "seq" / cam["name"] / "images" / f"{i:06d}.png").touch()
    if times is not None:
        (root / "seq" / "side" / "times.txt").write_text("".join(f"{t}\n" for t in times))
    return root / "seq"


def one_line(capsys) -> str:
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("ocalib calibrate: error: "), lines
    return lines[0]


@pytest.mark.parametrize("times, message", [
    (np.r_[np.arange(6), 4, np.arange(7, 12)] / 10, "strictly increasing"),
    (np.arange(11) / 10, "11 times for 12 images"),
    (["0.0", "zero"] + [str(i / 10) for i in range(2, 12)], "not a number"),
])  # fmt: skip
def test_a_bad_times_file_is_one_line(tmp_path, capsys, times, message):
    seq = layout(tmp_path, times=times)
    assert main(["calibrate", "--sequence", str(seq)]) == 2
    line = one_line(capsys)
    assert "side/times.txt" in line and message in line, line


def test_a_bad_true_offset_in_rig_yaml_is_one_line(tmp_path, capsys):
    seq = layout(tmp_path, time_offset="late")
    assert main(["calibrate", "--sequence", str(seq)]) == 2
    line = one_line(capsys)
    assert "rig.yaml: cameras[1] (side): time_offset must be a finite number" in line, line


@pytest.mark.parametrize("values, message", [
    (["soon"], "expected seconds or 'auto'"),
    (["nan"], "expected seconds or 'auto', got nan"),
    (["0.1", "inf"], "expected seconds or 'auto', got 0.1 inf"),
    (["0.1", "0.2"], "2 values for 1 cameras"),
])  # fmt: skip
def test_a_bad_time_offset_option_is_one_line(tmp_path, capsys, values, message):
    seq = layout(tmp_path)
    assert main(["calibrate", "--sequence", str(seq), "--time-offset", *values]) == 2
    assert message in one_line(capsys)
