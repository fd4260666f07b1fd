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
    if times is not None:  # every camera has its own stamps or none does: front's are good
        (root / "seq" / "front" / "times.txt").write_text("".join(f"{t / 10}\n" for t in range(frames)))
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


@pytest.mark.parametrize("lines, message", [
    (["0.0", "0.1", "nan"], "side/times.txt:3: timestamp is nan"),
    (["0.0", "inf"], "side/times.txt:2: timestamp is inf"),
    (["0.0", "0.1", "0.1"], "side/times.txt:3: duplicate timestamp"),
    (["# stamps", ""], "side/times.txt: no numbers in the file"),
    (["1700000000000000000", "1700000000.1"], "side/times.txt:2: stamp 1700000000.1 is in seconds, the first"),
    (["1700000000.0", "1700000000100000000"], "side/times.txt:2: stamp 1.7000000001e+18 is in nanoseconds"),
])  # fmt: skip
def test_a_malformed_times_file_names_its_line(tmp_path, capsys, lines, message):
    seq = layout(tmp_path, times=np.arange(12) / 10)
    (seq / "side" / "times.txt").write_text("\n".join(lines) + "\n")
    assert main(["calibrate", "--sequence", str(seq)]) == 2
    line = one_line(capsys)
    assert message in line, line


def test_a_folder_named_times_txt_is_refused(tmp_path, capsys):
    seq = layout(tmp_path, times=np.arange(12) / 10)
    (seq / "side" / "times.txt").unlink()
    (seq / "side" / "times.txt").mkdir()
    assert main(["calibrate", "--sequence", str(seq)]) == 2
    assert "side/times.txt: a folder, not a times file" in one_line(capsys)


def test_stamps_for_some_cameras_only_are_refused(tmp_path, capsys):
    seq = layout(tmp_path, times=np.arange(12) / 10)
    (seq / "side" / "times.txt").unlink()  # camera 0 alone has stamps: the others would be on no clock of theirs
    assert main(["calibrate", "--sequence", str(seq)]) == 2
    line = one_line(capsys)
    assert "side/times.txt: missing, while front has its own stamps" in line and "every camera's times.txt" in line


def test_a_dropped_frame_needs_the_cameras_stamps(tmp_path, capsys):
    seq = layout(tmp_path)
    (seq / "side" / "images" / "000005.png").unlink()
    assert main(["calibrate", "--sequence", str(seq)]) == 2
    assert "side/images/000005.png: frame is missing" in one_line(capsys)


def test_a_bad_true_offset_in_rig_yaml_is_one_line(tmp_path, capsys):
    seq = layout(tmp_path, time_offset="late")
    assert main(["calibrate", "--sequence", str(seq)]) == 2
    line = one_line(capsys)
    assert "rig.yaml: cameras[1] (side): time_offset must be a finite number" in line, line


@pytest.mark.parametrize("values, message", [
    (["soon"], "expected seconds or 'auto'"),
    (["nan"], "expected seconds or 'auto', got nan"),
    (["0.1", "inf"], "expected seconds or 'auto', got 0.1 inf"),
    (["0.1", "0.2"], "2 values for 1 camera besides the reference"),
])  # fmt: skip
def test_a_bad_time_offset_option_is_one_line(tmp_path, capsys, values, message):
    seq = layout(tmp_path)
    assert main(["calibrate", "--sequence", str(seq), "--time-offset", *values]) == 2
    assert message in one_line(capsys)
