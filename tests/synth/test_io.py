"""The written layout, determinism, presets = configs, and clear errors for bad input."""

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from ocalib.cli import main
from ocalib.data.rig import read_rig_yaml
from ocalib.errors import InputError
from ocalib.io.poses import read_kitti
from ocalib.synth import PRESETS, camera_poses, load_config, preset, render_sequence

CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "synth"
TINY = dict(frames=3, height=32, width=104)


def digest(folder: Path) -> dict:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_layout(tmp_path):
    cfg = preset("front-left").with_overrides(**TINY)
    out = render_sequence(cfg, tmp_path / "seq", progress=False)
    rig = read_rig_yaml(out / "rig.yaml")
    assert [c.name for c in rig.cameras] == ["front", "left"] and rig.frame_rate == 10.0
    assert np.allclose(rig.cameras[1].T_cam0_cam, cfg.cameras[1].T_cam0_cam())
    assert np.allclose(rig.cameras[0].K, [[0.58 * 104, 0, 0.5 * 104 - 0.5], [0, 1.92 * 32, 0.5 * 32 - 0.5], [0, 0, 1]])
    assert np.loadtxt(out / "times.txt").tolist() == [0.0, 0.1, 0.2]
    poses = camera_poses(cfg)
    for k, cam in enumerate(["front", "left"]):
        assert sorted(p.name for p in (out / cam / "images").iterdir()) == ["000000.png", "000001.png", "000002.png"]
        image = cv2.imread(str(out / cam / "images" / "000001.png"), cv2.IMREAD_UNCHANGED)
        depth = cv2.imread(str(out / cam / "depth" / "000001.png"), cv2.IMREAD_UNCHANGED)
        assert image.shape == (32, 104, 3) and image.dtype == np.uint8
        assert depth.shape == (32, 104) and depth.dtype == np.uint16 and depth.max() > 0
        written = read_kitti(out / cam / "poses.txt")
        assert np.abs(written - poses[k]).max() < 1e-6
    rel = np.linalg.inv(read_kitti(out / "front" / "poses.txt")) @ read_kitti(out / "left" / "poses.txt")
    assert np.abs(rel - rel[0]).max() < 1e-6


def test_same_seed_same_bytes_other_seed_differs(tmp_path):
    cfg = preset("handheld").with_overrides(**TINY)
    a = digest(render_sequence(cfg, tmp_path / "a", progress=False))
    b = digest(render_sequence(cfg, tmp_path / "b", progress=False))
    c = digest(render_sequence(cfg.with_overrides(seed=1), tmp_path / "c", progress=False))
    d = digest(render_sequence(cfg.with_overrides(frames=10), tmp_path / "d", progress=False, workers=2))
    assert a == b
    assert all(d[k] == v for k, v in a.items() if "images" in k or "depth" in k)  # workers change nothing
    assert a["cam0/images/000000.png"] != c["cam0/images/000000.png"]
    assert a["cam0/poses.txt"] != c["cam0/poses.txt"]


def test_photometric_only_when_asked(tmp_path):
    from ocalib.synth import render_rig

    cfg = preset("stereo").with_overrides(frames=1, height=32, width=104)
    plain, noisy = render_rig(cfg), render_rig(cfg.with_overrides(photometric=True))
    assert (plain.depth == noisy.depth).all()
    diff = (plain.images - noisy.images).abs().mean()
    assert 0.01 < diff < 0.3


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_config_files_equal_presets(name):
    assert load_config(CONFIGS / f"{name}.yaml") == preset(name)


def test_cli_writes_a_sequence(tmp_path, capsys):
    out = tmp_path / "cli"
    args = [
        "synth",
        "--config",
        str(CONFIGS / "stereo.yaml"),
        "--out",
        str(out),
        "--frames",
        "2",
        "--height",
        "32",
        "--width",
        "104",
        "--seed",
        "3",
    ]
    assert main(args) == 0
    assert len(list((out / "right" / "depth").iterdir())) == 2
    assert main(args) == 2  # not empty
    assert "not empty" in capsys.readouterr().err
    assert main(args + ["--overwrite"]) == 0


@pytest.mark.parametrize(
    "args, message",
    [
        (["--preset", "nope"], "unknown preset 'nope'"),
        (["--preset", "stereo", "--frames", "-1"], "bad frames: -1"),
        (["--preset", "stereo", "--frames", "0"], "bad frames: 0"),
        (["--preset", "stereo", "--height", "-5", "--width", "100"], "bad height: -5"),
        (["--preset", "stereo", "--width", "3"], "bad width: 3"),
        (["--config", "does/not/exist.yaml"], "no such config file"),
    ],
)
def test_cli_bad_input(tmp_path, capsys, args, message):
    assert main(["synth", *args, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    "text, message",
    [
        ("name: x\ncameras: [\n", "not valid YAML"),
        ("- just\n- a list\n", "expected a mapping"),
        ("name: x\ncameras:\n  - {name: a}\nframez: 3\n", "unknown field(s) framez"),
        ("name: x\ncameras:\n  - {name: a, fx: fast}\n", "malformed field"),
        ("name: x\ncameras:\n  - {name: a, focal: 2}\n", "malformed field"),
        ("name: x\ncameras:\n  - {name: a}\nframes: many\n", "malformed field"),
        ("name: x\ncameras:\n  - {name: a, position: [1, 0, 0]}\n", "camera 0"),
        ("name: x\ncameras:\n  - {name: a}\n  - {name: a}\n", "unique"),
        ("name: x\ncameras:\n  - {name: a}\ntrajectory: {kind: fly}\n", "trajectory.kind"),
        ("name: x\ncameras:\n  - {name: a}\ntrajectory: {kind: drive, speed: -3}\n", "speed"),
        ("name: x\ncameras:\n  - {name: a}\ntrajectory: {kind: drive, sped: 3}\n", "unknown option"),
        ("name: x\ncameras: []\n", "at least one camera"),
    ],
)
def test_malformed_config_is_a_clear_error(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=None) as info:
        cfg = load_config(path)
        render_sequence(cfg.with_overrides(frames=1, height=16, width=32), tmp_path / "out", progress=False)
    assert message in str(info.value)
    assert str(path) in str(info.value)


def test_config_round_trip(tmp_path):
    cfg = preset("front-rear").with_overrides(frames=7, seed=5)
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(cfg.to_dict()))
    assert load_config(path) == cfg


def test_cli_help_shows_the_defaults(capsys):
    """``ocalib synth --help`` gives each option's default, the numbers those of :class:`SynthConfig` (the presets')."""
    import dataclasses

    from ocalib.cli.synth import DEFAULTS
    from ocalib.synth import SynthConfig

    fields = {f.name: f.default for f in dataclasses.fields(SynthConfig)}
    assert DEFAULTS == {name: fields[name] for name in DEFAULTS}
    assert all(preset(name).frames == fields["frames"] for name in PRESETS)
    with pytest.raises(SystemExit):
        main(["synth", "--help"])
    options = capsys.readouterr().out.split("\noptions:\n")[1]
    entries = {e.split()[0]: " ".join(e.split()) for e in options.split("\n  -") if e.strip()}
    assert all("(default: " in entry for name, entry in entries.items() if name not in ("-h,", "-config"))
    for option, value in [*DEFAULTS.items(), ("preset", "front-rear"), ("device", "cpu"), ("photometric", "off")]:
        assert f"(default: {value}" in entries[f"-{option}"], entries[f"-{option}"]
