"""A user's mistakes on every command: one line naming what is wrong and exit code 2, never a traceback; Ctrl-C
stops with one line and exit code 130, saying what had been written; a rig without a ground truth is compared
with none."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from ocalib.cli import main
from ocalib.data.rig import CameraSpec, RigSpec, read_rig_yaml, write_rig_yaml
from ocalib.models import EgoMotionModel, save_model
from ocalib.synth import preset

ROOT = Path(__file__).resolve().parents[2]
NO_CUDA = pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")


def error_line(capsys, command: str) -> str:
    """The one line the command printed on stderr, which must be an error of ``command``."""
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"ocalib {command}: error: "), lines
    return lines[0]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("mistakes")
    (root / "binary.bin").write_bytes(bytes(range(256)) * 8)
    (root / "folder").mkdir()
    (root / "empty.txt").write_text("")
    (root / "nan.txt").write_text("nan 0 0 0 0 1 0 0 0 0 1 0\n" * 5)
    eye = "1 0 0 0 0 1 0 0 0 0 1 0\n"
    (root / "good.txt").write_text(eye * 5)
    return root


@pytest.fixture(scope="module")
def rig(tmp_path_factory, render):
    """A rendered 12-frame rig at 32x96, an untrained model at that size, and the same images played forwards and
    backwards for 240 frames as a user's rig: rig.yaml with names and intrinsics only, no poses."""
    root = tmp_path_factory.mktemp("rig")
    seq = render(preset("handheld").with_overrides(frames=12, height=32, width=96, seed=1003))
    torch.manual_seed(0)
    model = save_model(EgoMotionModel("small", height=32, width=96), root / "model.pt")
    spec = read_rig_yaml(seq / "rig.yaml")
    user = root / "user"
    order = [*range(12), *range(10, 0, -1)] * 11  # 242 frames, continuous motion
    for cam in spec.cameras:
        (user / cam.name / "images").mkdir(parents=True)
        for t, i in enumerate(order):
            (user / cam.name / "images" / f"{t:06d}.png").symlink_to(seq / cam.name / "images" / f"{i:06d}.png")
    write_rig_yaml(user / "rig.yaml", RigSpec([CameraSpec(c.name, c.width, c.height, c.K) for c in spec.cameras]))
    return seq, model, user


@NO_CUDA
@pytest.mark.parametrize("device", ["cuda", "cuda:1", "foo", "cpu:x"])
@pytest.mark.parametrize("command", [
    ["calibrate", "--sequence", "S"], ["predict", "--sequence", "S", "--out", "O"],
    ["evaluate", "--sequence", "S", "--out", "O"], ["synth", "--preset", "handheld"], ["demo"],
])  # fmt: skip
def test_an_unavailable_device_is_one_line(command, device, capsys, tmp_path):
    assert main([*command, "--device", device]) == 2
    assert f"--device {device}: " in error_line(capsys, command[0])
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("name, message", [
    ("binary.bin", "binary.bin: not a pose file (binary data at byte 0)"),
    ("folder", "folder: a folder, not a pose file"),
    ("missing.txt", "missing.txt: no such pose file"),
    ("empty.txt", "empty.txt: no poses in the file"),
    ("nan.txt", "too few frames: 0 with every pose valid"),
])  # fmt: skip
def test_a_bad_pose_file_is_one_line(files, name, message, capsys):
    assert main(["calibrate-poses", str(files / "good.txt"), str(files / name)]) == 2
    assert message in error_line(capsys, "calibrate-poses")


@pytest.mark.parametrize("option, message", [
    (["--plot", "folder"], "folder: a folder; --plot names the file to write"),
    (["--out", "folder"], "folder: a folder; --out names the file to write"),
    (["--times", "binary.bin", "binary.bin"], "binary.bin: not a"),
    (["--max-dt", "-1"], "--max-dt must be a positive number of seconds"),
])  # fmt: skip
def test_a_bad_option_of_calibrate_poses_is_one_line(files, option, message, capsys, monkeypatch):
    monkeypatch.chdir(files)
    assert main(["calibrate-poses", "good.txt", "good.txt", "--format", "kitti", *option]) == 2
    assert message in error_line(capsys, "calibrate-poses")


@pytest.mark.parametrize(
    "command", [["calibrate", "--sequence", "S"], ["calibrate-poses", "A", "B"], ["evaluate", "--sequence", "S"]]
)
@pytest.mark.parametrize("option", ["--out", "--trace", "--plot"])
def test_an_output_file_that_is_a_folder_is_refused_before_any_work(files, command, option, capsys, monkeypatch):
    """The inputs S, A, B do not exist: the output is checked first, so a mistake there costs no calibration."""
    if command[0] == "evaluate" and option != "--out":
        pytest.skip("evaluate has no such option")
    monkeypatch.chdir(files)
    assert main([*command, option, "folder"] + (["--out", "r.json"] if option != "--out" else [])) == 2
    assert f"folder: a folder; {option} names the file to write" in error_line(capsys, command[0])
    assert main([*command, option, "nowhere/r.json"] + (["--out", "r.json"] if option != "--out" else [])) == 2
    line = error_line(capsys, command[0])
    assert line.endswith(f"nowhere/r.json: no folder nowhere to write it in ({option})") or (
        option == "--plot" or command[0] == "evaluate"
    ), line


@pytest.mark.parametrize("option, message", [
    (["--checkpoint", "binary.bin"], "binary.bin: not a readable torch checkpoint"),
    (["--checkpoint", "folder"], "folder: a folder, not a checkpoint file"),
    (["--forgetting", "2"], "forgetting must be in (0, 1], got 2.0"),
    (["--cameras", "cam0", "nocam"], "no camera 'nocam'"),
    (["--metric-noise", "-0.1"], "--metric-noise must be a number of metres (0: held fixed) with --metric-trajectory"),
    (["--metric-noise", "inf"], "--metric-noise must be a number of metres (0: held fixed) with --metric-trajectory"),
])  # fmt: skip
def test_a_bad_option_of_calibrate_is_one_line(rig, files, option, message, capsys, monkeypatch):
    seq, model, _ = rig
    monkeypatch.chdir(files)
    args = ["calibrate", "--sequence", str(seq)]
    assert main(args + (option if option[0] == "--checkpoint" else ["--checkpoint", str(model), *option])) == 2
    assert message in error_line(capsys, "calibrate")


def test_a_folder_or_binary_file_as_sequence_or_config(files, capsys):
    assert main(["calibrate", "--sequence", str(files / "folder")]) == 2
    assert "folder: the folder is empty" in error_line(capsys, "calibrate")
    assert main(["predict", "--sequence", str(files / "binary.bin"), "--out", str(files / "p")]) == 2
    assert "binary.bin: not a sequence folder" in error_line(capsys, "predict")
    assert main(["synth", "--config", str(files / "binary.bin"), "--out", str(files / "s")]) == 2
    assert "binary.bin: not a YAML config (binary data at byte 0)" in error_line(capsys, "synth")
    assert main(["predict", "--sequence", "S", "--out", "O", "--workers", "-1"]) == 2
    assert "--workers must be >= 0" in error_line(capsys, "predict")


@pytest.mark.parametrize("args, message", [
    (["--config", "missing.yaml"], "missing.yaml: no such config file"),
    (["--config", "binary.bin"], "binary.bin: not a config file (binary data at byte 0)"),
    (["--config=folder"], "folder: a folder, not a config file"),
    (["--config", str(ROOT / "configs/train/synthetic-cpu.yaml"), "--nonsense", "3"], "unrecognized arguments"),
    (["--config", str(ROOT / "configs/train/synthetic-cpu.yaml"), "--trainer.accelerator", "foo"],
     "configuration: You selected an invalid accelerator name"),
])  # fmt: skip
def test_a_bad_training_command_is_one_line(files, args, message, capsys, monkeypatch):
    monkeypatch.chdir(files)
    assert main(["train", "fit", *args]) == 2  # caught: an uncaught exception would fail the test here
    last = capsys.readouterr().err.strip().splitlines()[-1]  # after Lightning's log lines
    assert message in last and last.startswith("ocalib train: error: ")


def test_a_rig_without_truth_is_compared_with_none(rig, tmp_path, capsys):
    """rig.yaml with names and intrinsics only: no extrinsic is taken for the truth, nothing is compared."""
    seq, model, user = rig
    spec = read_rig_yaml(user / "rig.yaml")
    assert [c.T_cam0_cam for c in spec.cameras] == [None, None]
    assert "T_cam0_cam" not in (user / "rig.yaml").read_text()
    out = tmp_path / "r.json"
    assert (
        main(
            [
                "calibrate",
                "--sequence",
                str(user),
                "--checkpoint",
                str(model),
                "--max-frames",
                "20",
                "--out",
                str(out),
                "--plot",
                str(tmp_path / "p.png"),
            ]
        )
        == 0
    )
    assert "ground truth" not in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert "ground_truth_errors" not in doc and doc["extrinsics"][0]["camera"] == "cam1"
    # the rendered rig, which has a truth, is compared with it
    assert main(["calibrate", "--sequence", str(seq), "--checkpoint", str(model), "--out", str(out)]) == 0
    assert "errors against the ground truth" in capsys.readouterr().out
    assert len(json.loads(out.read_text())["ground_truth_errors"]) == 1


def test_camera_0_is_the_identity_where_another_camera_has_a_truth(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [0.5, 0, 0]
    K = np.array([[100.0, 0, 47.5], [0, 100, 15.5], [0, 0, 1]])
    write_rig_yaml(tmp_path / "rig.yaml", RigSpec([CameraSpec("a", 96, 32, K), CameraSpec("b", 96, 32, K, T)]))
    spec = read_rig_yaml(tmp_path / "rig.yaml")
    np.testing.assert_array_equal(spec.cameras[0].T_cam0_cam, np.eye(4))
    np.testing.assert_array_equal(spec.cameras[1].T_cam0_cam, T)


def _children(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return []


def interrupt(args: list[str], cwd: Path, started=None) -> subprocess.CompletedProcess:
    """Run ``ocalib ARGS`` and press Ctrl-C (SIGINT to its process group, as a terminal does) once it has started
    its worker processes (the image loader, which starts once the head's kernel is compiled: minutes on a loaded
    machine with a cold numba cache) and ``started()`` holds, where given."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "ocalib", *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    deadline = time.time() + 900  # a guard: the wait is for the state
    while not (_children(proc.pid) and (started is None or started())) and proc.poll() is None:
        assert time.time() < deadline, "the command never reached the state to interrupt it in"
        time.sleep(0.02)
    assert proc.poll() is None, "finished before it could be interrupted"
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=300)  # a loaded machine can take minutes to wind the loader down
    return subprocess.CompletedProcess(args, proc.returncode, out, err)


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs /proc to see the worker processes")
def test_ctrl_c_during_calibrate_and_demo(rig, tmp_path):
    seq, model, user = rig
    done = interrupt(["calibrate", "--sequence", str(user), "--checkpoint", str(model), "--out", "r.json"], tmp_path)
    lines = [line for line in done.stderr.splitlines() if line.strip() and "frame/s" not in line]
    assert done.returncode == 130 and lines == ["ocalib calibrate: interrupted; nothing written"], done.stderr
    assert not (tmp_path / "r.json").exists()

    rendering = lambda: any((tmp_path / "d").rglob("*.png"))  # noqa: E731  (the renderer's pool at work)
    done = interrupt(["demo", "--out", "d", "--frames", "3000", "--checkpoint", str(model)], tmp_path, rendering)
    lines = [line for line in done.stderr.splitlines() if line.strip() and "frame/s" not in line]
    assert done.returncode == 130 and lines == ["ocalib demo: interrupted; written so far (incomplete): d"], done.stderr


@pytest.mark.parametrize("command", [["calibrate", "--sequence", "S"], ["calibrate-poses", "A", "B"]])
def test_a_plot_in_a_missing_folder_is_refused_like_the_result(tmp_path, command, capsys, monkeypatch):
    """``--plot`` names a file, as ``--out`` does: a folder that is not there is a mistake, not one to make."""
    monkeypatch.chdir(tmp_path)
    assert main([*command, "--out", "r.json", "--plot", "nodir/x.png"]) == 2
    assert error_line(capsys, command[0]).endswith("nodir/x.png: no folder nodir to write it in (--plot)")
    assert not (tmp_path / "nodir").exists()


def test_training_without_a_config_says_to_give_one(capsys):
    assert main(["train", "fit"]) == 2
    assert (
        error_line(capsys, "train") == "ocalib train: error: fit: give a config, e.g. --config configs/train/quick.yaml"
    )


def test_calibrate_says_which_front_end_ran_when_it_was_given(rig, capsys):
    seq, _, _ = rig
    assert main(["calibrate", "--sequence", str(seq), "--frontend", "opencv", "--no-bundle-adjust"]) == 0
    assert "front end: opencv (--frontend opencv)" in capsys.readouterr().out.splitlines()


@pytest.mark.parametrize("args", [["--data.sequences=data/my-video"], ["--data.sequences", "data/my-video"]])
def test_a_list_option_of_train_given_one_folder_is_one_line(args, capsys):
    """Caught before Lightning is imported (jsonargparse's own message is a paragraph about Union subtypes)."""
    assert main(["train", "fit", "--config", str(ROOT / "configs/train/folder.yaml"), *args]) == 2
    assert error_line(capsys, "train") == (
        "ocalib train: error: --data.sequences takes a list: --data.sequences '[data/my-video]' "
        "(several: '[DIR1, DIR2]')"
    )


def test_a_synth_error_names_the_command_lines_override(tmp_path, capsys):
    """The overrides go in before the config's checks: --frames 100 below a change at frame 150 is the error, named
    as given; --frames 300 over a file of 100 frames makes that change valid."""
    config = tmp_path / "knock.yaml"
    cameras = "cameras:\n- {name: a}\n- {name: b, position: [0.5, 0, 0], change: {frame: 150, rotation_deg: [0, 1, 0], position: [0, 0, 0]}}\n"
    config.write_text(f"name: knock\nframes: 200\n{cameras}")
    assert main(["synth", "--config", str(config), "--frames", "100", "--out", str(tmp_path / "s")]) == 2
    line = error_line(capsys, "synth")
    assert f"{config} with --frames 100: camera b: change: frame must be an integer in [1, 99] (frames: 100)" in line
    config.write_text(f"name: knock\nframes: 100\n{cameras}")
    from ocalib.synth import load_config

    assert load_config(config, frames=300).frames == 300
