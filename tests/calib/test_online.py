import math

import pytest
import torch
from calib_helpers import car_rig, lds_rig, no_gating

from ocalib.calib.drivers.batch import batch_calibrate
from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.geometry import make_pose, rotation_angle
from ocalib.geometry.quaternion import so3_exp
from ocalib.sim.trajectory import add_noise, random_rig, rig_trajectories, straight_trajectory


def rotation_error_deg(R, R_true):
    return math.degrees(rotation_angle(R.mT @ R_true).max().item())


@pytest.mark.parametrize("motion", ["first", "consecutive", "multi"])
@pytest.mark.parametrize("symmetric", [True, False])
def test_closed_form_equals_batch_every_frame(generator, motion, symmetric):
    poses, _, _ = lds_rig(generator, frames=64, noise=0.01)
    cal = OnlineCalibrator(2, motion=motion, refine=False, symmetric=symmetric, **no_gating())
    compared = 0
    for t in range(len(poses)):
        out = cal(poses[t])
        if t < 4 or out.planar_motion.any():  # the planar route is not part of the batch reference
            continue
        ref = batch_calibrate(poses[: t + 1], motion, symmetric=symmetric, refine=False)
        torch.testing.assert_close(out.quaternion[0], ref["quaternion"], atol=1e-8, rtol=0)
        torch.testing.assert_close(out.translation[0], ref["translation"], atol=1e-8, rtol=0)
        torch.testing.assert_close(out.scale[0], ref["scale"], atol=1e-8, rtol=0)
        torch.testing.assert_close(out.rotation_singular_values[0], ref["singular_values"], atol=1e-8, rtol=0)
        compared += 1
    assert compared > 30


@pytest.mark.parametrize(("motion", "symmetric"), [("first", True), ("multi", True), ("multi", False)])
def test_refined_equals_batch_joint_least_squares(generator, motion, symmetric):
    """The O(1) refinement equals Levenberg-Marquardt on all stacked rows (an independent implementation), each
    direction of the translation rows weighed by its own residual variance, re-estimated once at the solution."""
    poses, _, _ = lds_rig(generator, frames=40, noise=0.01)
    cal = OnlineCalibrator(2, motion=motion, symmetric=symmetric, **no_gating())
    refined = 0
    for t in range(len(poses)):
        out = cal(poses[t])
        # From frame 10: at frame 9 the third rotation direction is barely excited (S = 0.13 over a noise floor
        # of 0.06) and the three O(1) steps stop 1.4e-8 short of the batch minimum.
        if t < 10 or t % 3 or out.planar_motion.any():
            continue
        ref = batch_calibrate(poses[: t + 1], motion, symmetric=symmetric)
        torch.testing.assert_close(out.quaternion[0], ref["quaternion"], atol=1e-8, rtol=0)
        torch.testing.assert_close(out.translation[0], ref["translation"], atol=1e-8, rtol=0)
        torch.testing.assert_close(out.scale[0], ref["scale"], atol=1e-8, rtol=0)
        refined += int(ref["refined"].all())
    assert refined >= 8
    # ... and it moved away from the closed form (by more than the tolerance).
    closed = batch_calibrate(poses, motion, symmetric=symmetric, refine=False)
    assert (out.quaternion[0] - closed["quaternion"]).abs().max() > 1e-5


@pytest.mark.parametrize("cameras", [2, 3])
@pytest.mark.parametrize("solver", ["exact", "rls"])
def test_noise_free_rigs_are_recovered(generator, cameras, solver):
    rigs = [lds_rig(generator, frames=80, cameras=cameras) for _ in range(3)]
    poses = torch.stack([r[0] for r in rigs], 1)  # (T, B, C, 4, 4)
    # The paper's RLS keeps the rows it saw with early (wrong) rotations: start it once rotation is known.
    cal = OnlineCalibrator(cameras, batch_size=3, solver=solver, rls_c0=1e9, rls_delay=10)
    for t in range(len(poses)):
        out = cal(poses[t])
    for b, (_, X, s) in enumerate(rigs):
        assert rotation_error_deg(out.rotation[b], X[:, :3, :3]) < 1e-6
        torch.testing.assert_close(out.translation[b], X[:, :3, 3], atol=1e-6, rtol=0)
        torch.testing.assert_close(out.scale[b], s, atol=1e-6, rtol=0)
        assert out.rotation_observable[b].all() and not out.planar_motion[b].any()


def test_state_dict_resumes_mid_stream(generator):
    poses, _, _ = lds_rig(generator, frames=60, noise=0.01)
    full = OnlineCalibrator(2)
    for t in range(60):
        expected = full(poses[t])
    first = OnlineCalibrator(2)
    for t in range(25):
        first(poses[t])
    second = OnlineCalibrator(2)
    second.load_state_dict(first.state_dict())
    for t in range(25, 60):
        out = second(poses[t])
    torch.testing.assert_close(out.quaternion, expected.quaternion, atol=0, rtol=0)
    torch.testing.assert_close(out.translation, expected.translation, atol=0, rtol=0)


def test_bad_poses_are_skipped_and_counted(generator):
    poses, X, s = lds_rig(generator, frames=80)
    bad = poses.clone()
    bad[10, 1, 0, 0] = float("nan")
    bad[20, 0, :3, 3] = float("inf")
    bad[30, 1, :3, :3] *= 1.1  # not a rotation
    cal = OnlineCalibrator(2)
    for t in range(len(bad)):
        out = cal(bad[t])
    assert out.frames_rejected.item() == 3
    assert out.frames_used.item() == 80 - 1 - 3
    assert rotation_error_deg(out.rotation[0], X[:, :3, :3]) < 1e-6
    torch.testing.assert_close(out.translation[0], X[:, :3, 3], atol=1e-6, rtol=0)
    assert all(torch.isfinite(v).all() for v in (out.quaternion, out.translation, out.scale, out.rotation_std))


def test_screw_gate_rejects_outlier_motions(generator):
    poses, X, _ = lds_rig(generator, frames=120, noise=0.002)
    outliers = poses.clone()
    for t in range(40, 120, 9):  # camera 1 jumps by 20 degrees for one frame
        outliers[t, 1] = outliers[t, 1] @ make_pose(
            so3_exp(torch.tensor([0.35, 0.0, 0.0], dtype=torch.float64)), torch.zeros(3, dtype=torch.float64)
        )
    gated, plain = OnlineCalibrator(2), OnlineCalibrator(2, **no_gating())
    for t in range(len(poses)):
        out_g, out_p = gated(outliers[t]), plain(outliers[t])
    err_g = rotation_error_deg(out_g.rotation[0], X[:, :3, :3])
    err_p = rotation_error_deg(out_p.rotation[0], X[:, :3, :3])
    assert err_g < 0.3 < err_p


def biased_translations(poses, camera, angle):
    """The trajectory of ``camera`` re-chained with every frame-to-frame translation turned by ``angle`` (rad) about
    that camera's x axis: a monocular front end's biased translation directions (rotations untouched)."""
    P = poses[:, camera]
    motion = torch.linalg.inv(P[:-1]) @ P[1:]
    turn = so3_exp(torch.tensor([angle, 0.0, 0.0], dtype=torch.float64))
    motion[:, :3, 3] = motion[:, :3, 3] @ turn.mT
    chained = [P[0]]
    for m in motion:
        chained.append(chained[-1] @ m)
    out = poses.clone()
    out[:, camera] = torch.stack(chained)
    return out


def test_refine_unobservable_keeps_biased_translations_off_an_observable_rotation(generator):
    """refine="unobservable" is the closed form where rotation is observable, so translation directions that are
    15 degrees off (a monocular front end) cannot pull the rotation, as they pull the joint refinement's."""
    poses, X, _ = lds_rig(generator, frames=100, noise=0.002)
    biased = biased_translations(poses, 1, math.radians(15))
    heads = {mode: OnlineCalibrator(2, refine=mode) for mode in (True, "unobservable", False)}
    for t in range(len(poses)):
        out = {mode: head(biased[t]) for mode, head in heads.items()}
    assert out["unobservable"].rotation_observable.all() and not out["unobservable"].refined.any()
    torch.testing.assert_close(out["unobservable"].quaternion, out[False].quaternion, atol=1e-12, rtol=0)
    err = {mode: rotation_error_deg(o.rotation[0], X[:, :3, :3]) for mode, o in out.items()}
    assert err["unobservable"] < 0.15 and err[True] > 1.5 * err["unobservable"]
    with pytest.raises(ValueError, match="refine must be one of"):
        OnlineCalibrator(2, refine="sometimes")


def test_planar_motion_is_flagged_and_rotation_recovered(generator):
    poses, X = car_rig(generator, frames=300, noise=0.001)
    cal = OnlineCalibrator(2)
    for t in range(len(poses)):
        out = cal(poses[t])
    assert out.planar_motion.item() and not out.rotation_observable.item()
    assert rotation_error_deg(out.rotation[0], X[:, :3, :3]) < 0.5
    # The unobservable translation direction is the rotation axis: camera 0's y axis (the car's vertical).
    unobservable = out.translation_directions[0, 0][:, out.translation_unobservable[0, 0]]
    assert unobservable.shape[1] == 1 and abs(unobservable[1, 0].item()) > 0.99
    assert math.isinf(out.translation_std[0, 0, 1].item())
    # ... and its component is reported as the minimum-norm value, not as noise.
    assert abs((out.translation[0, 0] * out.planar_axis[0, 0]).sum().item()) < 1e-12
    # The observable (ground-plane) components are right.
    torch.testing.assert_close(out.translation[0, 0, [0, 2]], X[0, [0, 2], 3], atol=0.05, rtol=0)


def test_pure_translation_is_rotation_unobservable(generator):
    X = random_rig(generator)[None]
    poses = add_noise(rig_trajectories(straight_trajectory(100), X), 1e-4, generator)
    cal = OnlineCalibrator(2)
    for t in range(len(poses)):
        out = cal(poses[t])
    assert not out.rotation_observable.item() and not out.planar_motion.item()
    assert out.translation_unobservable.all()


def test_gradcheck_through_the_stream(generator):
    poses, _, _ = lds_rig(generator, frames=12, noise=0.01)
    # Perturb camera 1's rotation vector at every frame, keeping the inputs valid poses.
    delta = torch.zeros(12, 3, dtype=torch.float64, requires_grad=True)

    def run(delta):
        p = poses.clone()
        p = torch.cat([p[:, :1], (p[:, 1] @ make_pose(so3_exp(delta), torch.zeros_like(delta)))[:, None]], 1)
        cal = OnlineCalibrator(2, motion="multi", **no_gating())
        for t in range(len(p)):
            out = cal(p[t])
        return out.quaternion, out.translation, out.scale

    assert torch.autograd.gradcheck(run, (delta,), atol=1e-6, fast_mode=True)


def test_gradients_stay_finite_on_planar_motion(generator):
    poses, _ = car_rig(generator, frames=40)
    poses = poses.clone().requires_grad_()
    cal = OnlineCalibrator(2)
    for t in range(len(poses)):
        out = cal(poses[t])
    (out.quaternion.sum() + out.translation.sum() + out.scale.sum()).backward()
    assert torch.isfinite(poses.grad).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_any_input_dtype_and_device(generator, device, dtype):
    poses, X, s = lds_rig(generator, frames=60)
    cal = OnlineCalibrator(2, device=device)
    for t in range(len(poses)):
        out = cal(poses[t].to(device=device, dtype=dtype))
    assert out.translation.device.type == device.type and out.translation.dtype == torch.float64
    tol = 1e-4 if dtype == torch.float32 else 1e-8
    torch.testing.assert_close(out.translation[0].cpu(), X[:, :3, 3], atol=tol * 10, rtol=0)


def test_wrong_shape_is_a_clear_error():
    with pytest.raises(ValueError, match=r"expected poses of shape \(1, 2, 4, 4\)"):
        OnlineCalibrator(2)(torch.eye(4, dtype=torch.float64).expand(3, 4, 4))


def test_gradients_after_an_inference_mode_stream(generator):
    """Constants cached during an inference-mode run must not break a later autograd run."""
    poses, _, _ = lds_rig(generator, frames=10, noise=0.01)
    with torch.inference_mode():
        cal = OnlineCalibrator(2)
        for t in range(len(poses)):
            cal(poses[t])
    poses = poses.clone().requires_grad_()
    cal = OnlineCalibrator(2)
    for t in range(len(poses)):
        out = cal(poses[t])
    out.translation.sum().backward()
    assert torch.isfinite(poses.grad).all()
