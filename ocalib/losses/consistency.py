"""Geometry consistency of SC-SfMLearner (Bian et al. 2019): depth of the target points seen from the source
must agree with the source's own depth there.

Convention: depths (B, 1, H, W) in the same (network) units.
"""

from __future__ import annotations

from torch import Tensor


def depth_inconsistency(projected: Tensor, sampled: Tensor) -> Tensor:
    """``|D_proj - D_src| / (D_proj + D_src)`` in [0, 1) (B, 1, H, W); ``1 - it`` is the self-discovered mask."""
    return (projected - sampled).abs() / (projected + sampled).clamp(min=1e-6)
