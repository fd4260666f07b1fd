"""The compiled CPU kernel (``backend="auto"`` on the CPU) equals the PyTorch head at every frame (each stage's
compiled twin against its PyTorch function: the test module of the stage's module)."""

import copy

import pytest
import torch
from calib_helpers import car_rig, lds_rig

from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.stages.rotation import rotation_gram as gram

kernel = pytest.importorskip("ocalib.calib.drivers.kernel", reason="numba is not installed")

TOL = dict(atol=1e-8, rtol=1e-8)


def assert_same_frame(a, b, t):
    """Frame t of the kernel (a) and of PyTorch (b): flags exactly, numbers to 1e-8."""
    for name in ("rotation_observable", "planar_motion", "refined", "frames_used", "frames_rejected"):
        assert torch.equal(getattr(a, name), getattr(b, name)), f"frame {t}: {name}"
    for name in ("rotation_singular_values", "rotation_rows", "translation_rows", "translation_moment",
                 "translation_moment_reverse"):  # fmt: skip
        torch.testing.assert_close(getattr(a, name), getattr(b, name), **TOL, msg=f"frame {t}: {name}")
    S2a, S2b = a.rotation_singular_values.square(), b.rotation_singular_values.square()
    torch.testing.assert_close(gram(S2a, a.rotation_basis), gram(S2b, b.rotation_basis), **TOL, msg=f"frame {t}: M")
    # The estimate is unique where rotation is observable, planar (the translation route) or refined, with 3 motion
    # pairs at least: with fewer, the planar route's 6 unknowns are underdetermined and rounding picks the solution.
    determined = (a.rotation_observable | a.planar_motion | a.refined) & (a.translation_rows >= 3)
    for name in ("quaternion", "rotation", "translation", "scale"):
        torch.testing.assert_close(
            getattr(a, name)[determined], getattr(b, name)[determined], **TOL, msg=f"frame {t}: {name}"
        )
    # The planar axis: its sign is the eigenvectors' choice.
    torch.testing.assert_close(a.planar_axis.abs(), b.planar_axis.abs(), **TOL, msg=f"frame {t}: planar axis")


def assert_same_state(a, b):
    for name, buffer in b.named_buffers():
        if name.endswith("V"):  # eigenvectors: compared through the Gram matrix they span
            continue
        torch.testing.assert_close(a.get_buffer(name), buffer, **TOL, msg=name)
    torch.testing.assert_close(gram(a.gap_S2, a.gap_V), gram(b.gap_S2, b.gap_V), **TOL)


def stream(poses, **options):
    """Both backends over ``poses`` (T, B, C, 4, 4) frame by frame; returns the two heads."""
    fast = OnlineCalibrator(poses.shape[2], poses.shape[1], **options)
    slow = OnlineCalibrator(poses.shape[2], poses.shape[1], backend="torch", **options)
    for t in range(len(poses)):
        assert_same_frame(fast(poses[t]), slow(poses[t]), t)
    return fast, slow


def batch_of_rigs(generator, rigs, **kwargs):
    """(T, B, C, 4, 4): ``rigs`` independent noisy rigs."""
    return torch.stack([lds_rig(generator, **kwargs)[0] for _ in range(rigs)], 1)


@pytest.mark.parametrize("motion", ["first", "consecutive", "multi", (1, 3)])
@pytest.mark.parametrize("refine", [True, False, "unobservable"])
def test_equals_torch_head_every_frame(generator, motion, refine):
    poses = batch_of_rigs(generator, 2, frames=48, noise=0.01)
    fast, slow = stream(poses, motion=motion, refine=refine)
    assert_same_state(fast, slow)


@pytest.mark.parametrize("scale_fit", ["symmetric", "regression"])
def test_equals_torch_head_with_either_scale_fit(generator, scale_fit):
    poses = batch_of_rigs(generator, 2, frames=48, noise=0.02)
    poses[:, :, 1:, :3, 3] /= 2.5  # camera 1 in other units
    fast, slow = stream(poses, scale_fit=scale_fit)
    assert_same_state(fast, slow)


@pytest.mark.parametrize("symmetric", [True, False])
def test_equals_torch_head_three_cameras_forgetting_and_drift(generator, symmetric):
    poses = batch_of_rigs(generator, 2, frames=48, cameras=3, noise=0.01, model="drift")
    fast, slow = stream(poses, symmetric=symmetric, forgetting=0.97)
    assert_same_state(fast, slow)


def test_equals_torch_head_on_many_rigs_in_parallel(generator):
    """Enough rigs for the multi-threaded loop (kernel.PARALLEL_MIN_RIGS)."""
    assert kernel.PARALLEL_MIN_RIGS <= 20
    poses = batch_of_rigs(generator, 20, frames=24, noise=0.02)
    stream(poses)


def test_equals_torch_head_on_planar_motion(generator):
    poses, _ = car_rig(generator, frames=80, noise=0.002)
    fast, _ = stream(poses[:, None])
    assert fast(poses[-1]).planar_motion.all()  # the planar route was exercised


def test_equals_torch_head_with_bad_poses_and_outliers(generator):
    """NaN and non-orthonormal poses are skipped; gross outliers meet the screw gate and the robust weights."""
    poses, _, _ = lds_rig(generator, frames=60, noise=0.01)
    poses = poses.clone()
    poses[7, 1, 0, 0] = float("nan")
    poses[12, 0, :3, :3] *= 1.1  # not a rotation
    poses[30, 1, :3, :3] = poses[30, 1, :3, :3] @ torch.linalg.matrix_exp(
        torch.tensor([[0.0, -0.3, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    )  # 17 degrees off
    fast, slow = stream(poses[:, None])
    assert fast.frames_rejected.item() >= 2
    assert_same_state(fast, slow)


def test_state_dict_moves_between_backends_mid_stream(generator):
    poses = batch_of_rigs(generator, 2, frames=40, noise=0.01)
    fast = OnlineCalibrator(2, 2)
    for t in range(20):
        fast(poses[t])
    slow = OnlineCalibrator(2, 2, backend="torch")
    slow.load_state_dict(copy.deepcopy(fast.state_dict()))
    for t in range(20, 40):
        assert_same_frame(fast(poses[t]), slow(poses[t]), t)


def test_pytorch_runs_where_the_kernel_does_not_apply(generator):
    """Gradients, the RLS solver and float32 run in PyTorch (the kernel would not give them)."""
    poses, _, _ = lds_rig(generator, frames=12, noise=0.01)
    head = OnlineCalibrator(2)
    x = poses.clone().requires_grad_(True)
    for t in range(len(x)):
        out = head(x[t])
    out.translation.sum().backward()
    assert x.grad is not None and x.grad.abs().sum() > 0
    assert not OnlineCalibrator(2, solver="rls")._kernel_applies(poses[0], False)
    assert not OnlineCalibrator(2, dtype=torch.float32)._kernel_applies(poses[0], False)
    assert OnlineCalibrator(2)._kernel_applies(poses[0], False)
    with pytest.raises(ValueError, match="backend"):
        OnlineCalibrator(2, backend="numpy")


def test_results_held_by_the_caller_are_not_overwritten(generator):
    """The kernel reuses its output memory only once no result (or view of one) is alive."""
    poses, _, _ = lds_rig(generator, frames=20, noise=0.01)
    head = OnlineCalibrator(2)
    for t in range(10):
        head(poses[t])
    kept = head(poses[10])
    moment, rotation = kept.translation_moment[0, 0], kept.rotation
    snapshot = (moment.clone(), rotation.clone())
    del kept
    for t in range(11, 20):
        out = head(poses[t])
    assert torch.equal(moment, snapshot[0]) and torch.equal(rotation, snapshot[1])
    assert not torch.equal(out.translation_moment[0, 0], moment)  # the stream went on
