"""A bad lens in rig.yaml: one line naming the file and the camera, exit code 2, from every command that reads it."""

from __future__ import annotations

import pytest
import yaml

from ocalib.cli import main

K = [[104.0, 0.0, 103.5], [0.0, 102.4, 31.5], [0.0, 0.0, 1.0]]


@pytest.mark.parametrize("command", [["calibrate", "--sequence"], ["predict", "--out", "O", "--sequence"]])
@pytest.mark.parametrize("entry, message", [
    ({"model": "kb4", "coeffs": [0, 0, 0, 0]}, "unknown model 'kb4'"),
    ({"model": "opencv", "coeffs": [0.1, 0, 0, 0]}, "needs 5 coeffs"),
    ({"model": "fisheye", "coeffs": [0.1, 0, "k3", 0]}, "coeffs must be finite numbers"),
    ({"model": "fisheye", "coeffs": [0.1, 0, ".nan", 0]}, "coeffs must be finite numbers"),
])  # fmt: skip
def test_a_bad_distortion_is_one_line(tmp_path, capsys, monkeypatch, command, entry, message):
    monkeypatch.chdir(tmp_path)
    cameras = [
        {"name": "front", "width": 208, "height": 64, "K": K},
        {"name": "side", "width": 208, "height": 64, "K": K},
    ]
    cameras[1]["distortion"] = entry
    text = yaml.safe_dump({"frame_rate": 10.0, "cameras": cameras}).replace("'.nan'", ".nan")
    (tmp_path / "seq").mkdir()
    (tmp_path / "seq" / "rig.yaml").write_text(text)
    for cam in cameras:
        (tmp_path / "seq" / cam["name"] / "images").mkdir(parents=True)
        (tmp_path / "seq" / cam["name"] / "images" / "000000.png").touch()
    assert main([*command, "seq"]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"ocalib {command[0]}: error: "), lines
    assert "rig.yaml: cameras[1] (side): distortion" in lines[0] and message in lines[0], lines
