"""The joint rig bundle adjustment on COLMAP: one rig trajectory explains every camera's features, so the
translation between non-overlapping cameras is recovered where each camera's monocular scale cannot give it.

Modules: :mod:`~ocalib.rigba.options` (settings, light to import), :mod:`~ocalib.rigba.colmap` (the boundary
conversions), :mod:`~ocalib.rigba.workspace` (images, features, matches), :mod:`~ocalib.rigba.mapping` (COLMAP's
mappers), :mod:`~ocalib.rigba.covariance` (uncertainty and observability), :mod:`~ocalib.rigba.adjust` (the stage)
and :mod:`~ocalib.rigba.stage` (after the on-line pass of ``ocalib calibrate``). Importing this package does not load
COLMAP; import the module you need.
"""
