"""ocalib: on-line calibration of non-overlapping multi-camera rigs from ego-motion.

Conventions (used everywhere in the package):

* A pose is camera-to-world, a 4x4 matrix (KITTI pose files: 12 numbers a line, row-major 3x4).
  A camera's trajectory is re-referenced to its own first frame before calibration.
* An extrinsic ``T_cam0_cam1`` is the pose of camera 1 in camera 0's frame: ``p_cam0 = R p_cam1 + t``.
  The scale ``s`` multiplies camera-1 trajectory units into camera-0 units. Camera 0 is the reference.
* Quaternions are (w, x, y, z), as in kornia. Calibration math runs in float64.
* Images are (B, C, H, W) in [0, 1]; intrinsics K are (B, 3, 3) in pixels with integer pixel centres.
"""

__version__ = "0.1.0"
