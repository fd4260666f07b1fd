import hashlib
import os
import shutil

import pytest
import torch
from filelock import FileLock  # torch's own dependency

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(params=DEVICES)
def device(request):
    return torch.device(request.param)


@pytest.fixture
def generator():
    return torch.Generator().manual_seed(1234)


@pytest.fixture(scope="session")
def render(tmp_path_factory):
    """``render(config, workers=1) -> Path``: ``config`` (a synth config) rendered once for the whole test run, in a
    folder pytest-xdist's workers share (the renderer gives the same bytes for the same config; a module fixture
    alone renders once per worker). Read only: a test that changes the images works on a copy."""
    base = tmp_path_factory.getbasetemp()
    root = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "renders"
    root.mkdir(exist_ok=True)

    def rendered(config, workers: int = 1):
        from ocalib.synth import render_sequence

        path = root / f"{config.name}-{hashlib.sha256(repr(config).encode()).hexdigest()[:16]}"
        with FileLock(f"{path}.lock"):
            if not path.exists():
                partial = path.with_name(path.name + ".partial")  # a failed render leaves no folder at path
                shutil.rmtree(partial, ignore_errors=True)
                render_sequence(config, partial, progress=False, workers=workers)
                partial.rename(path)
        return path

    return rendered


# The slow tests (node ids under tests/, or their prefixes): a render, a training run, a whole command, a compile.
# `pytest -m "not slow"` leaves them out (the edit-test loop); the whole suite runs them.
SLOW = (
    "calib/test_absolute.py::test_beats_opencv_on_its_own_protocol",
    "calib/test_compile.py",
    "calib/test_numba_cache.py",
    "calib/test_online.py::test_gradcheck_through_the_stream",
    "calib/test_online.py::test_refined_equals_batch_joint_least_squares",
    "calib/test_translation.py::test_head_scale_against_frame0_batch",
    "calibnet/test_calibnet_cli.py",
    "calibnet/test_calibnet_kitti.py",
    "calibnet/test_own_frames.py::test_calibrate_runs_to_the_end",
    "calibnet/test_unsynchronised.py",
    "cli/test_calibrate_poses.py::test_kitti_end_to_end",
    "cli/test_calibrate_poses.py::test_three_cameras_and_solvers",
    "cli/test_user_mistakes.py::test_a_rig_without_truth_is_compared_with_none",
    "cli/test_user_mistakes.py::test_ctrl_c_during_calibrate_and_demo",
    "data/test_rosbag.py::test_a_bags_odometry_is_the_metric_trajectory_and_its_gap_said",
    "data/test_rosbag.py::test_calibrating_a_bag_gives_the_folders_extrinsics",
    "eval/test_eval_predict.py",
    "frontend/test_frontend_registry.py::test_the_opencv_front_end_is_opencv_vo_per_camera",
    "frontend/test_opencv_vo.py",
    "losses/test_losses_warp.py::test_warp_gradcheck_float64",
    "rigba/test_adjust.py",
    "rigba/test_calibrate_bundle.py",
    "rigba/test_rig_online.py::test_a_rendered_rig_is_followed_and_its_knocked_camera_noticed",
    "rigba/test_rig_online.py::test_a_trajectory_off_as_a_real_one_is_needs_its_noise_stated",
    "rigba/test_rig_online.py::test_the_windows_solved_poses_take_the_metric_positions_as_priors",
    "rigba/test_rig_online.py::test_a_textureless_stretch_is_counted_not_fatal",
    "rigba/test_rig_online.py::test_a_candidate_raised_at_the_streams_end_is_reported_unjudged",
    "sim/test_experiment.py::test_cli_end_to_end",
    "sim/test_readme_table.py",
    "synth/test_change.py::test_rendered_layout_holds_the_truth",
    "synth/test_io.py::test_cli_writes_a_sequence",
    "synth/test_late_camera.py::test_the_layout_holds_the_cameras_stamps_and_the_true_offset",
    "synth/test_io.py::test_same_seed_same_bytes_other_seed_differs",
    "test_packaging.py::test_train_runs_from_a_folder_holding_train_py",
    "train/test_train_compile.py",
    "train/test_train_ddp.py",
    "train/test_train_nan_guard.py::test_nonfinite_loss_step_is_skipped",
    "train/test_train_run.py",
    "train/test_train_schedule.py::test_the_trainer_anneals_by_its_max_time",
    "viz/test_calibration_plot.py::test_plot_with_truth_writes_a_png",
)


def pytest_collection_modifyitems(items):
    """Mark the tests of :data:`SLOW` slow."""
    for item in items:
        if item.nodeid.removeprefix("tests/").startswith(SLOW):
            item.add_marker(pytest.mark.slow)
