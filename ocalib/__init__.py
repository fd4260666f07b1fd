"""ocalib: on-line calibration of non-overlapping multi-camera rigs from ego-motion.

Conventions (used everywhere in the package):

* A pose is camera-to-world, a 4x4 matrix (KITTI pose files: 12 numbers a line, row-major 3x4).
  A camera's trajectory is re-referenced to its own first frame before calibration.
* An extrinsic ``T_cam0_cam1`` is the pose of camera 1 in camera 0's frame: ``p_cam0 = R p_cam1 + t``.
  The scale ``s`` multiplies camera-1 trajectory units into camera-0 units. Camera 0 is the reference.
* Quaternions are (w, x, y, z), as in kornia. Calibration math runs in float64.
* Images are (B, C, H, W) in [0, 1]; intrinsics K are (B, 3, 3) in pixels with integer pixel centres.

The public API, each name loaded on first use (``import ocalib`` stays light):

* :class:`OnlineCalibrator`, :class:`HeadOptions`: the on-line head on a stream of poses.
* :func:`calibrate_files`: ``ocalib calibrate-poses`` on trajectory files.
* :func:`calibrate_images`: ``ocalib calibrate``'s on-line pass on an image sequence; :func:`refine_calibration`
  adds the rig bundle adjustment to its result.
* :class:`OnlineRigEstimator`: the whole extrinsic on-line from images and a metric trajectory.
* :func:`open_sequence`: an image sequence on disk in any of its layouts (:data:`ocalib.data.layout.LAYOUTS`:
  ocalib's rig layout, KITTI raw, KITTI odometry, SfMLearner, a plain image folder with an intrinsics file).

The README has a runnable example of each; the guide, the method, the architecture and the references are in docs/.
"""

from importlib import import_module

__version__ = "0.1.0"

_PUBLIC = {
    "OnlineCalibrator": "ocalib.calib.drivers.online",
    "HeadOptions": "ocalib.calib.drivers.options",
    "calibrate_files": "ocalib.calib.poses.pipeline",
    "calibrate_images": "ocalib.calibnet.run",
    "refine_calibration": "ocalib.calibnet.bundle",
    "OnlineRigEstimator": "ocalib.rigba.online",
    "open_sequence": "ocalib.data.layout",
}
__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name not in _PUBLIC:
        raise AttributeError(f"module 'ocalib' has no attribute {name!r}")
    value = getattr(import_module(_PUBLIC[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
