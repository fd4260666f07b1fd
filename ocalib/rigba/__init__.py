"""The joint rig bundle adjustment on COLMAP: one rig trajectory explains every camera's features, so the translation
between non-overlapping cameras is recovered where each camera's monocular scale cannot give it. Modules of the batch
adjustment: :mod:`~ocalib.rigba.options` (settings, light to import), :mod:`~ocalib.rigba.colmap` (the boundary
conversions), :mod:`~ocalib.rigba.workspace` (images, features, matches), :mod:`~ocalib.rigba.mapping` (COLMAP's
mappers), :mod:`~ocalib.rigba.metric_prior` (a metric trajectory as priors), :mod:`~ocalib.rigba.covariance`
(uncertainty and observability), :mod:`~ocalib.rigba.lens_check` (a missing lens), :mod:`~ocalib.rigba.adjust` (the
solve), :mod:`~ocalib.rigba.trust` (what can be used), :mod:`~ocalib.rigba.result` (the outcome and its JSON) and
:mod:`~ocalib.rigba.evaluate` (against the truth); the stage after the on-line pass of ``ocalib calibrate`` is
:mod:`ocalib.calibnet.bundle`. The on-line estimator: :mod:`~ocalib.rigba.online` with its
:mod:`~ocalib.rigba.local_map` (keyframes and points), :mod:`~ocalib.rigba.camera_state` (each camera's phase),
:mod:`~ocalib.rigba.window`, :mod:`~ocalib.rigba.change` test, :mod:`~ocalib.rigba.features` and :mod:`~ocalib.rigba.stream` (in ``ocalib
calibrate``). Importing this package does not load COLMAP; import the module you need.
"""
