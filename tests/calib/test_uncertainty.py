import math
from dataclasses import fields

import torch
from calib_helpers import car_rig, lds_rig

from ocalib.calib.drivers.online import OnlineCalibrator
from ocalib.calib.drivers.result import Calibration
from ocalib.calib.drivers.sequence import calibrate_sequence
from ocalib.calib.stages.rotation import rotation_std
from ocalib.geometry import rotation_angle


def frame(out: Calibration, t: int) -> Calibration:
    return Calibration(**{f.name: getattr(out, f.name)[t] for f in fields(Calibration)})


def test_planar_rotation_std_matches_the_errors(generator):
    """On planar motion the rotation std comes from the planar route, not from the degenerate rotation system."""
    rigs = [car_rig(generator, frames=200, noise=0.002) for _ in range(30)]
    poses, X = torch.stack([r[0] for r in rigs], 1), torch.stack([r[1][0] for r in rigs])
    with torch.no_grad():
        last = frame(calibrate_sequence(poses), -1)
    assert last.planar_motion.all()
    error = rotation_angle(last.rotation[:, 0].mT @ X[:, :3, :3])
    predicted = last.rotation_std[:, 0].norm(dim=-1)
    ratio = (error.square().mean() / predicted.square().mean()).sqrt().item()
    assert 0.4 < ratio < 2.0, ratio
    degenerate = rotation_std(last.rotation_singular_values, last.rotation_basis, last.rotation_rows)[:, 0].norm(dim=-1)
    assert (degenerate > 10 * predicted).all()


def test_std_is_infinite_until_the_residual_tells(generator):
    """With one motion pair the systems are exactly determined (or under): no residual, no std (not 0)."""
    poses, _, _ = lds_rig(generator, frames=6, noise=0.01)
    cal = OnlineCalibrator(2, motion="consecutive")
    cal(poses[0])
    one = cal(poses[1])
    assert math.isinf(one.scale_std.item()) and one.translation_std.isinf().all() and one.rotation_std.isinf().all()
    for t in range(2, 6):
        out = cal(poses[t])
    assert out.scale_std.isfinite().all() and out.rotation_std.isfinite().all()
    assert one.camera_json(0, 0)["scale_std"] is None


def test_refined_std_matches_the_errors(generator):
    """Where refined, the std is the joint solve's: rotation, translation and scale within ~2x of the errors."""
    rigs = [lds_rig(generator, frames=100, noise=0.01) for _ in range(30)]
    poses, X = torch.stack([r[0] for r in rigs], 1), torch.stack([r[1][0] for r in rigs])
    s = torch.stack([r[2] for r in rigs])
    with torch.no_grad():
        last = frame(calibrate_sequence(poses), -1)
    assert last.refined.all()
    pairs = [
        (rotation_angle(last.rotation[:, 0].mT @ X[:, :3, :3]), last.rotation_std[:, 0].norm(dim=-1)),
        ((last.translation[:, 0] - X[:, :3, 3]).norm(dim=-1), last.translation_std[:, 0].norm(dim=-1)),
        (last.scale[:, 0] - s[:, 0], last.scale_std[:, 0]),
    ]
    for error, predicted in pairs:
        ratio = (error.square().mean() / predicted.square().mean()).sqrt().item()
        assert 0.5 < ratio < 2.5, ratio
