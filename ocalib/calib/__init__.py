"""The calibration math: rig extrinsics and scale from every camera's ego-motion (the paper's on-line head and its
references). Free of Lightning; float64; import the module you need (numba loads only with the compiled kernels).

By role:

* **The head's stages**, each a pure function with its compiled numba twin beside it (``*_kernel.py``, equal to
  1e-8): :mod:`~ocalib.calib.gating` (pose checks, screw-congruence gate, weights), :mod:`~ocalib.calib.pairing`
  (which frame pairs give rows), :mod:`~ocalib.calib.handeye` (the hand-eye rows), :mod:`~ocalib.calib.rotation`
  (incremental SVD), :mod:`~ocalib.calib.planar` (rotation under planar motion), :mod:`~ocalib.calib.translation`
  (translation and scale), :mod:`~ocalib.calib.solve` (the closed form), :mod:`~ocalib.calib.refine` (the joint
  refinement), :mod:`~ocalib.calib.linalg` (eigen-decomposition with finite gradients).
* **The drivers**: :mod:`~ocalib.calib.online` (:class:`OnlineCalibrator`, frame by frame), :mod:`~ocalib.calib.kernel`
  (its compiled frame update), :mod:`~ocalib.calib.sequence` (a recorded sequence at once),
  :mod:`~ocalib.calib.batch` (the batch reference solver), :mod:`~ocalib.calib.absolute` (``AX = YB`` from absolute
  poses).
* **Around them**: :mod:`~ocalib.calib.options` (the head's settings), :mod:`~ocalib.calib.result` (one frame's
  estimate), :mod:`~ocalib.calib.change` (a change of the extrinsic told from noise), :mod:`~ocalib.calib.clock`
  (the clock offset between cameras).
* **The application** ``ocalib calibrate-poses``: :mod:`~ocalib.calib.pipeline` (pose files in, the calibration
  out) and :mod:`~ocalib.calib.report` (its JSON, trace, warnings and summary).
"""
