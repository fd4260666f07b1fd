"""The front-end interface: every registered front end builds for a sequence, reads its frames and returns each
camera's motion; the OpenCV front end equals OpenCV VO run on each camera alone; the command line lists the
registry."""

import numpy as np
import pytest
import torch

from ocalib.cli import build_parser
from ocalib.data.image_io import read_image
from ocalib.data.layout import open_sequence
from ocalib.errors import InputError
from ocalib.frontend import AUTO, FRONTENDS, FrontEndOptions, build_frontend, frontend_class
from ocalib.frontend.base import FrontEnd
from ocalib.frontend.opencv_vo import run_opencv_vo
from ocalib.geometry.se3 import chain_motions
from ocalib.models import EgoMotionModel, save_model
from ocalib.synth import preset


@pytest.fixture(scope="module")
def sequence(render):
    return open_sequence(render(preset("handheld").with_overrides(frames=12, seed=7, height=96, width=312)))


def stream(front_end: FrontEnd, sequence, frames: int) -> np.ndarray:
    """Each camera's chained motions over the first ``frames`` frames -> (T, C, 4, 4)."""
    dataset = front_end.frames(sequence)
    C = len(sequence.cameras)
    with torch.inference_mode():
        motions = [
            front_end(dataset[t], torch.eye(3, dtype=torch.float64).expand(1, C - 1, 3, 3)) for t in range(frames)
        ]
    motions = torch.cat(motions).double().numpy()  # (T, C, 4, 4)
    assert np.allclose(motions[0], np.eye(4))  # the first frame: no motion
    return np.stack([chain_motions(motions[1:, c]) for c in range(C)], 1)


@pytest.mark.parametrize("name", list(FRONTENDS))
def test_every_registered_front_end_is_a_front_end(name):
    assert issubclass(frontend_class(name), FrontEnd)


def test_the_opencv_front_end_is_opencv_vo_per_camera(sequence):
    front_end = build_frontend(sequence, FrontEndOptions("opencv"))
    poses = stream(front_end, sequence, 8)
    for c, camera in enumerate(sequence.cameras):
        images = [(read_image(p, camera.size) * 255).round().byte().permute(1, 2, 0).numpy() for p in camera.images[:8]]
        reference, _ = run_opencv_vo(images, camera.K)
        np.testing.assert_allclose(poses[:, c], reference, atol=1e-9)
    front_end.reset()  # a new stream starts again at the identity
    np.testing.assert_allclose(stream(front_end, sequence, 2)[:, 0], poses[:2, 0], atol=1e-9)


def test_the_network_front_end_reads_frames_at_the_models_resolution(sequence, tmp_path):
    checkpoint = save_model(EgoMotionModel("small", height=32, width=96), tmp_path / "model.pt")
    front_end = build_frontend(sequence, FrontEndOptions("network", str(checkpoint)))
    assert front_end.frames(sequence)[0].shape == (2, 3, 32, 96)
    assert front_end.align and front_end.rig_align  # the network's defaults
    poses = stream(front_end, sequence, 3)
    assert poses.shape == (3, 2, 4, 4) and np.isfinite(poses).all()


@pytest.mark.parametrize(
    "options, message",
    [
        (FrontEndOptions("foo"), "unknown front end 'foo'"),
        (FrontEndOptions("opencv", align=True), "align refines the pose network"),
        (FrontEndOptions("network", align=False, rig_align=True), "rig-align .* needs align"),
        (FrontEndOptions("network", scale="bar"), "unknown scale mode"),
    ],
)
def test_contradicting_front_end_options_are_refused(options, message):
    with pytest.raises(InputError, match=message):
        options.resolved()


@pytest.mark.parametrize("command", ["calibrate", "demo"])
def test_the_command_line_lists_the_registry(command):
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    frontend = next(a for a in sub._actions if a.dest == "frontend")
    assert tuple(frontend.choices) == (*FRONTENDS, AUTO) and frontend.default == AUTO
