"""The calibration math: rig extrinsics and scale from every camera's ego-motion (the paper's on-line head and its
references). Free of Lightning; float64; import the module you need (numba loads only with the compiled kernels).

Three sub-packages, each importing only from those above it here:

* :mod:`ocalib.calib.stages`: the head's stages, each a pure function with its compiled numba twin beside it
  (``*_kernel.py``, equal to 1e-8): ``gating`` (pose checks, screw-congruence gate, weights), ``pairing`` (which frame
  pairs give rows), ``handeye`` (the hand-eye rows), ``rotation`` (incremental SVD), ``planar`` (rotation under planar
  motion), ``translation`` (translation and scale), ``solve`` (the closed form), ``refine`` (the joint refinement),
  ``linalg`` (eigen-decomposition with finite gradients).
* :mod:`ocalib.calib.drivers`: ``online`` (:class:`OnlineCalibrator`, frame by frame), ``kernel`` (its compiled frame
  update), ``sequence`` (a recorded sequence at once), ``batch`` (the batch reference solver), ``absolute``
  (``AX = YB`` from absolute poses); around them ``options`` (the head's settings), ``result`` (one frame's
  estimate), ``change`` (a change of the extrinsic told from noise), ``clock`` (the clock offset between cameras).
* :mod:`ocalib.calib.poses`: the application ``ocalib calibrate-poses``, ``pipeline`` (pose files in, the calibration
  out) and ``report`` (its JSON, trace, warnings and summary).
"""
