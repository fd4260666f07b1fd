"""COLMAP's mappers over a rig workspace: one rig trajectory for every camera's frames, with the rig's
``sensor_from_rig`` refined in the bundle adjustments and the intrinsics held as given.

The mappers are :data:`ocalib.rigba.options.MAPPERS`; the incremental one can continue from an earlier reconstruction.

Convention: as :mod:`ocalib.rigba.colmap`; the reconstruction's units are its own (COLMAP's gauge).
"""

from __future__ import annotations

from pathlib import Path

import pycolmap

from ocalib.rigba.options import MAPPERS, MapperOptions
from ocalib.rigba.workspace import Workspace


def global_options(options: MapperOptions) -> pycolmap.GlobalPipelineOptions:
    """COLMAP's global pipeline options for a rig with (by default) fixed intrinsics."""
    out = pycolmap.GlobalPipelineOptions()
    out.num_threads = options.threads
    out.random_seed = options.seed
    ba = out.mapper.bundle_adjustment
    ba.refine_focal_length = ba.refine_principal_point = options.refine_intrinsics
    ba.refine_extra_params = False
    ba.refine_sensor_from_rig = True
    return out


def incremental_options(options: MapperOptions) -> pycolmap.IncrementalPipelineOptions:
    """COLMAP's incremental pipeline options for a rig with (by default) fixed intrinsics."""
    out = pycolmap.IncrementalPipelineOptions()
    out.ba_refine_focal_length = options.refine_intrinsics
    out.ba_refine_principal_point = options.refine_intrinsics
    out.ba_refine_extra_params = False
    out.ba_refine_sensor_from_rig = True
    out.num_threads = options.threads
    out.random_seed = options.seed
    out.mapper.random_seed = options.seed
    out.mapper.abs_pose_refine_focal_length = options.refine_intrinsics
    out.mapper.abs_pose_refine_extra_params = False
    return out


def map_rig(
    ws: Workspace, options: MapperOptions = MapperOptions(), previous: Path | None = None
) -> list[pycolmap.Reconstruction]:
    """The reconstructions of ``ws``, the one with the most registered frames first; ``previous``: a reconstruction
    folder the incremental mapper continues from (its frames stay registered and new ones are added)."""
    out = ws.root / "sparse"
    out.mkdir(exist_ok=True)
    if options.kind not in MAPPERS:
        raise ValueError(f"unknown mapper {options.kind!r}: {', '.join(MAPPERS)}")
    if options.kind == "global" and previous is None:
        models = pycolmap.global_mapping(ws.database, ws.images, out, global_options(options))
    else:
        models = pycolmap.incremental_mapping(
            ws.database, ws.images, out, options=incremental_options(options), input_path=previous or ""
        )
    return sorted(models.values(), key=lambda r: r.num_reg_frames(), reverse=True)
