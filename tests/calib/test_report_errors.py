"""The ground-truth error lines: a figure the estimate does not define (a straight drive's translation direction,
a zero baseline, a front end's rotation gain about an axis it never turned) is printed as n/a with its reason,
never as a NaN; defined figures are printed as computed. The summary's frame counts say whose they are."""

import math

import numpy as np
import pytest

from ocalib.calib.poses.report import errors_table
from ocalib.rigba.covariance import ExtrinsicUncertainty
from ocalib.rigba.evaluate import adjustment_errors
from ocalib.rigba.result import RigAdjustment


def _adjustment(t_estimate: np.ndarray, unobservable: np.ndarray) -> RigAdjustment:
    """A metric adjustment of a two-camera rig: camera 1 at ``t_estimate``, those translation directions unobservable."""
    extrinsics = np.tile(np.eye(4), (2, 1, 1))
    extrinsics[1, :3, 3] = t_estimate
    return RigAdjustment(
        extrinsics,
        np.ones(2, bool),
        [None, ExtrinsicUncertainty(np.eye(6) * 1e-8, unobservable)],
        np.ones(2),
        np.arange(5),
        np.tile(np.eye(4), (5, 1, 1)),
        np.ones((5, 2), bool),
        "metres",
    )


def _truth(t_true: np.ndarray):
    """True extrinsics (2, 4, 4) with camera 1 at ``t_true``, and a straight drive's poses (5, 2, 4, 4) along z."""
    extrinsics = np.tile(np.eye(4), (2, 1, 1))
    extrinsics[1, :3, 3] = t_true
    poses = np.tile(np.eye(4), (5, 2, 1, 1))
    poses[:, :, 2, 3] = np.arange(5.0)[:, None]
    return extrinsics, poses


def test_a_straight_drive_prints_no_nan_but_says_the_direction_is_undefined():
    t_true = np.array([0.5, 0.1, 0.2])
    extrinsics, poses = _truth(t_true)
    # only the drive's axis observed: two translation directions unobservable, so no direction to compare
    errors = adjustment_errors(_adjustment(t_true + 0.01, np.array([[1.0, 0, 0], [0, 1.0, 0]])), extrinsics, poses)
    assert math.isnan(errors[0]["translation_direction_error_deg"])
    text = errors_table(errors, ["cam0", "cam1"], "after the rig bundle adjustment")
    assert "nan" not in text.lower()
    assert "translation direction n/a (fewer than two of its components observable)" in text
    # the translation along the observable axis is still a figure, over the whole baseline: 0.01 m of 0.548 m
    assert f"translation 0.010 m = {0.01 / np.linalg.norm(t_true):.1%} of the baseline" in text


def test_all_directions_unobservable_says_the_translation_is_undetermined_instead_of_nan():
    t_true = np.array([0.5, 0.1, 0.2])
    extrinsics, poses = _truth(t_true)
    errors = adjustment_errors(_adjustment(t_true, np.eye(3)), extrinsics, poses)
    text = errors_table(errors, ["cam0", "cam1"])
    assert "nan" not in text.lower()
    assert "translation n/a (no direction of it determined)" in text


def test_defined_figures_print_as_computed_and_undefined_head_figures_as_n_a():
    a, b = np.array([1.0, 0.0, 0.0]), np.array([1.0, 1.0, 0.0])
    error = {
        "camera": 1,
        "rotation_error_deg": 0.1234,
        "translation_direction_error_deg": math.degrees(math.acos(a @ b / np.linalg.norm(b))),  # 45 deg
        "compared_in_plane": False,
        "metric_scale": math.nan,
        "translation_error": 0.02,
        "translation_error_rel_baseline": 0.1,
        "scale": 0.98,
        "scale_true": math.nan,
        "rotation_gain_reference": [1.0, math.nan, 0.99],
        "rotation_gain": [math.nan, 1.01, 1.0],
        "scale_wander": math.nan,
        "lever_arm_signal": math.nan,
        "wander_window": 20,
    }
    text = errors_table([error], ["cam0", "cam1"])
    assert "nan" not in text.lower()
    assert "rotation 0.123 deg, translation direction 45.00 deg, translation 0.020 m = 10.0% of the baseline" in text
    assert "(camera 0 scaled to metres xn/a), scale 0.980 (true n/a)" in text
    assert "cam0 1.00/n/a/0.99, cam1 n/a/1.01/1.00" in text
    nan_direction = dict(error, translation_direction_error_deg=math.nan)
    assert "translation direction n/a (a zero translation has no direction)" in errors_table(
        [nan_direction], ["a", "b"]
    )


def _camera(source: str | None, used: int, rejected: int) -> dict:
    """A camera's result JSON as ``calibrate`` writes it, from ``source`` (None: the on-line head)."""
    e = {
        "camera": "cam1",
        "quaternion_wxyz": [1.0, 0.0, 0.0, 0.0],
        "translation": [0.1, 0.0, 0.0],
        "translation_std": [0.01, 0.01, 0.01],
        "rotation_std_deg": [0.1, 0.1, 0.1],
        "scale": 1.0,
        "scale_std": 0.01,
        "time_offset": None,
        "frames_used": used,
        "frames_rejected": rejected,
        "observability": {
            "rotation_observable": True,
            "planar_motion": False,
            "unobservable_translation_directions": [],
        },
        "residuals": {"rotation_deg": 0.1, "translation_relative": 0.01},
    }
    if source is not None:
        e["source"] = source
    return e


def test_the_summary_says_what_its_frame_counts_count():
    from ocalib.calib.poses.report import summary

    settings = {"frames": 300, "solver": "exact", "motion": "multi"}
    doc = {"reference": "cam0", "settings": settings, "extrinsics": [_camera("bundle_adjustment", 148, 2)]}
    first = summary(doc).splitlines()[1]
    assert first == "cam1: from the rig bundle adjustment; 148 of 150 keyframes registered in the bundle adjustment"
    doc["extrinsics"] = [_camera(None, 297, 3)]
    first = summary(doc).splitlines()[1]
    assert first == "cam1: from the on-line head; the on-line head used 297 frames and rejected 3"


def test_a_cars_translation_is_compared_in_the_ground_plane_whatever_the_stage_claims():
    """On a planar drive the adjustment's height (here claimed observable) is left out of the car's figures, as the
    head's is, and said apart: 0.2 m off in y with x and z exact is no error in the plane, 0.2 m of height."""
    t_true = np.array([-0.9, 0.3, -1.0])
    extrinsics, poses = _truth(t_true)
    estimate = _adjustment(t_true + [0.0, 0.2, 0.0], np.zeros((0, 3)))
    [free] = adjustment_errors(estimate, extrinsics, poses)
    assert not free["compared_in_plane"] and free["translation_error"] == pytest.approx(0.2)
    assert free["height_error"] is None
    [car] = adjustment_errors(estimate, extrinsics, poses, plane=np.array([[0.0, 1.0, 0.0]]))
    assert car["compared_in_plane"] and car["translation_error"] == pytest.approx(0.0, abs=1e-12)
    assert car["translation_direction_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert car["height_error"] == pytest.approx(0.2)
    # the error in the plane over the whole lever arm: 0.1 m off along x is 0.1 / |(-0.9, 0.3, -1.0)|
    [off] = adjustment_errors(_adjustment(t_true + [0.1, 0.2, 0.0], np.zeros((0, 3))), extrinsics, poses,
                              plane=np.array([[0.0, 1.0, 0.0]]))  # fmt: skip
    assert off["translation_error_rel_baseline"] == pytest.approx(0.1 / np.linalg.norm(t_true))
