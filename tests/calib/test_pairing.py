import numpy as np
import pytest
import torch
from calib_helpers import lds_rig, random_moment, random_orthonormal, random_poses

from ocalib.calib.drivers.batch import batch_calibrate
from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.stages import pairing_kernel
from ocalib.calib.stages.gating import NO_GATES
from ocalib.calib.stages.handeye import STATISTICS, TranslationMoment
from ocalib.calib.stages.pairing import (
    GAP_PRIOR_DOF,
    GAP_WEIGHT_POWER,
    MotionPairs,
    combine_statistics,
    gap_weights,
    motions_since,
)
from ocalib.calib.stages.rotation import RotationSystem, rotation_gram


def _system(residual: list[float], rows: list[float]) -> tuple[torch.Tensor, torch.Tensor]:
    """Squared singular values (P, 4) whose smallest is the residual, and row counts (P,)."""
    S2 = torch.tensor([[100.0, 50.0, 20.0, r] for r in residual], dtype=torch.float64)
    return S2, torch.tensor(rows, dtype=torch.float64)


def test_gap_weights_closed_form():
    # Equal noise: all weights 1. Gap 2 twice as noisy: (1/2 shrunk toward the pooled variance)^power.
    S2, rows = _system([1.0, 1.0], [1001.5, 1001.5])  # 2000 degrees of freedom each
    torch.testing.assert_close(gap_weights(S2, rows), torch.ones(2, dtype=torch.float64))
    S2, rows = _system([1.0, 2.0], [1001.5, 1001.5])
    residual, prior_dof = torch.tensor([1.0, 2.0], dtype=torch.float64), GAP_PRIOR_DOF
    shrunk = (residual + prior_dof * 3.0 / 4000) / (2000 + prior_dof)  # toward the pooled variance
    var = (residual + prior_dof * shrunk.max()) / (2000 + prior_dof)  # toward the noisiest gap's
    expected = (var[0] / var) ** GAP_WEIGHT_POWER
    torch.testing.assert_close(gap_weights(S2, rows), expected, rtol=1e-9, atol=0)
    # A gap without residual degrees of freedom counts as the noisiest measured gap and does not set the reference.
    S2, rows = _system([0.0, 1.0, 2.0], [1.0, 1001.5, 1001.5])
    w = gap_weights(S2, rows)
    shrunk = (residual + prior_dof * 3.0 / 4000) / (2000 + prior_dof)
    var = (residual + prior_dof * shrunk.max()) / (2000 + prior_dof)
    assert w[1] == 1
    # (up to the rounding floor, 1e-12 of the largest signal per row: 1e-10 with the new gap's single row)
    torch.testing.assert_close(w[1:], (var[0] / var) ** GAP_WEIGHT_POWER, rtol=1e-5, atol=0)
    torch.testing.assert_close(w[0], (var[0] / shrunk.max()) ** GAP_WEIGHT_POWER, rtol=1e-5, atol=0)
    # Without any measured gap, all weigh 1.
    S2, rows = _system([0.0, 0.0], [1.0, 1.0])
    assert bool((gap_weights(S2, rows) == 1).all())


def test_noise_free_weights_are_one(generator):
    poses, _, _ = lds_rig(generator, frames=40)
    cal = OnlineCalibrator(2)
    for t in range(len(poses)):
        cal(poses[t])
    w = gap_weights(cal.gap_S2, cal.gap_rotation_rows)
    torch.testing.assert_close(w, torch.ones_like(w), atol=1e-4, rtol=0)  # rounding against the floor


@pytest.mark.parametrize("model", ["independent", "drift"])
def test_long_gaps_fade_under_drift_only(generator, model):
    """Against the noise the simulator put in: under drift a gap-16 motion is 16x as noisy as a consecutive
    one and its weight falls to nothing; under independent noise all gaps are alike and keep their weight."""
    poses, _, _ = lds_rig(generator, frames=128, noise=0.01, model=model)
    cal = OnlineCalibrator(2, motion=(1, 2, 4, 8, 16))
    for t in range(len(poses)):
        cal(poses[t])
    w = gap_weights(cal.gap_S2, cal.gap_rotation_rows)[0, 0]
    if model == "drift":
        assert w[0] == 1 and w[4] < 1e-4 and bool((w[1:].diff() < 0).all())
    else:
        assert bool((w > 0.3).all())


def test_new_long_gap_starts_light_under_drift(generator):
    """Under drift, gap 16's first rows (frame 16) come in at about the weight of the noisiest gap already
    measured (gap 8: 8x the variance of gap 1), not at weight 1."""
    poses, _, _ = lds_rig(generator, frames=18, noise=0.01, model="drift")
    cal = OnlineCalibrator(2, motion=(1, 2, 4, 8, 16))
    for t in range(17):
        cal(poses[t])
    assert 0 < float(cal.gap_rotation_rows[0, 0, 4]) <= 1  # one (robustly weighted) row
    w = gap_weights(cal.gap_S2, cal.gap_rotation_rows)[0, 0]
    assert w[4] < 0.01 and w[4] <= 1.5 * w[3]


def test_weighted_gaps_equal_the_weighted_batch_under_drift(generator):
    """Where the weights matter (drift), the stream still equals the batch solve with the same weights."""
    poses, _, _ = lds_rig(generator, frames=48, noise=0.01, model="drift")
    cal = OnlineCalibrator(2, refine=False, gates=NO_GATES)
    for t in range(len(poses)):
        out = cal(poses[t])
    ref = batch_calibrate(poses, "multi", refine=False)
    torch.testing.assert_close(out.quaternion[0], ref["quaternion"], atol=1e-8, rtol=0)
    torch.testing.assert_close(out.translation[0], ref["translation"], atol=1e-8, rtol=0)
    assert gap_weights(cal.gap_S2, cal.gap_rotation_rows).min() < 0.1  # the weights did matter


def test_motions_since_twin(generator):
    B, C, P = 4, 3, 5
    earlier, poses = random_poses(generator, B, C, P, scale=2.0), random_poses(generator, B, C, scale=2.0)
    earlier_valid, valid = torch.rand(B, C, P, generator=generator) < 0.8, torch.rand(B, C, generator=generator) < 0.8
    want = motions_since(earlier, earlier_valid, poses, valid)
    for b in range(B):
        got = MotionPairs(np.empty((C, P, 4, 4)), np.empty((C, P, 4)), np.empty((C, P)), np.empty((C - 1, P), bool))
        pairing_kernel.motions_since(
            earlier[b].numpy(), earlier_valid[b].numpy(), poses[b].numpy(), valid[b].numpy(), got
        )
        for name, value in zip(MotionPairs._fields, got):
            np.testing.assert_allclose(value, getattr(want, name)[b].numpy(), rtol=0, atol=1e-12, err_msg=name)


@pytest.mark.parametrize("gaps", [5, 1])
def test_combine_statistics_twin(generator, gaps):
    """Gaps with and without residual degrees of freedom; the twin decomposes in the last frame's basis."""
    B = 6
    S2 = torch.rand(B, gaps, 4, generator=generator, dtype=torch.float64) * torch.tensor([10, 10, 10, 1])
    S2 = S2.sort(-1, descending=True).values
    rows = torch.rand(B, gaps, generator=generator, dtype=torch.float64) * 40
    rows[0] = 1.0  # no gap measured: all weigh 1
    gaps_ = RotationSystem(S2, random_orthonormal(generator, B, gaps), rows)
    moment = TranslationMoment(
        random_moment(generator, B, gaps),
        40 * torch.rand(B, gaps, generator=generator, dtype=torch.float64),
        random_moment(generator, B, gaps),
    )
    want_rotation, want_moment, want_weights = combine_statistics(rotation_gram(S2, gaps_.V), S2, rows, moment)
    basis = random_orthonormal(generator, B)
    for b in range(B):
        S2_b, V_b, work = np.empty(4), basis[b].numpy().copy(), pairing_kernel.workspace(gaps)
        Z_b, Z_reverse_b = np.empty(STATISTICS), np.empty(STATISTICS)
        got_rows, got_translation_rows = pairing_kernel.combine_statistics(
            RotationSystem(*(x[b].numpy() for x in gaps_)), TranslationMoment(*(x[b].numpy() for x in moment)), S2_b,
            V_b, Z_b, Z_reverse_b, work,
        )  # fmt: skip
        if gaps > 1:
            np.testing.assert_allclose(work.weights, want_weights[b].numpy(), rtol=1e-10, atol=0)
        np.testing.assert_allclose(got_rows, want_rotation.rotation_rows[b].item(), rtol=1e-12)
        np.testing.assert_allclose(got_translation_rows, want_moment.translation_rows[b].item(), rtol=1e-12)
        np.testing.assert_allclose(Z_b, want_moment.Z[b].numpy(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(Z_reverse_b, want_moment.Z_reverse[b].numpy(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(S2_b, want_rotation.S2[b].numpy(), rtol=0, atol=1e-12 * S2_b[0])
        M = rotation_gram(torch.from_numpy(S2_b), torch.from_numpy(V_b))
        torch.testing.assert_close(
            M, rotation_gram(want_rotation.S2[b], want_rotation.V[b]), rtol=0, atol=1e-12 * S2_b[0]
        )
