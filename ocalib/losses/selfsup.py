"""The self-supervised objective: monodepth2's minimum reprojection with auto-masking, multi-scale, edge-aware
smoothness, SC-SfMLearner's geometry consistency with its self-discovered mask (optional), and a scale gauge
(:mod:`ocalib.losses.gauge`).

Convention: ``images`` (B, S, 3, H, W), the target first then S-1 sources; ``T_source_target`` (B, S-1, 4, 4)
maps target-camera points into each source camera; ``K`` (B, 3, 3) at (H, W); disparities (B, 1, h, w) per scale.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ocalib.losses.consistency import depth_inconsistency
from ocalib.losses.gauge import scale_gauge
from ocalib.losses.photometric import photometric_error
from ocalib.losses.smoothness import edge_aware_smoothness
from ocalib.losses.warp import inverse_warp
from ocalib.models.depth import disp_to_depth
from ocalib.models.egomotion import MAX_DEPTH, MIN_DEPTH

INVALID = 1e3  # error given to reprojections outside the source image, so another source wins the minimum


@dataclass
class LossOutput:
    """``total`` (scalar); ``terms``: named scalars for logging; ``images``: (B, ...) maps for logging
    (``warped`` first source at scale 0, ``valid`` its mask, ``used`` pixels entering the loss)."""

    total: Tensor
    terms: dict[str, Tensor] = field(default_factory=dict)
    images: dict[str, Tensor] = field(default_factory=dict)


def min_reprojection(reprojection: Tensor, identity: Tensor, automask: bool = True) -> tuple[Tensor, Tensor]:
    """Per-pixel minimum over sources (B, S', H, W) -> (error, used) (B, 1, H, W).

    ``identity``: the errors of the unwarped sources (no gradient). With ``automask`` (monodepth2) they compete
    in the minimum: where an unwarped source matches better (a static scene, or an object moving with the
    camera) the pixel is not ``used`` and contributes that constant error. Without, they only stand in for
    pixels that project outside every source. Either way every pixel counts in the mean, so the networks
    cannot lower the loss by pushing hard pixels out of it.
    """
    identity = identity.detach()
    if automask:
        error, index = torch.cat([reprojection, identity], 1).min(1, keepdim=True)
        return error, (index < reprojection.shape[1]).to(error.dtype)
    error = reprojection.min(1, keepdim=True).values
    used = error < INVALID
    return torch.where(used, error, identity.min(1, keepdim=True).values), used.to(error.dtype)


def masked_mean(x: Tensor, mask: Tensor) -> Tensor:
    return (x * mask).sum() / mask.sum().clamp(min=1.0)


def identity_errors(images: Tensor, ssim: float = 0.85, automask: bool = True) -> Tensor:
    """The photometric errors of the unwarped sources against the target (B, S-1, H, W), no gradient; with
    ``automask``, plus a 1e-5 noise that breaks ties with the reprojections (monodepth2)."""
    with torch.no_grad():
        target, sources = images[:, 0], images[:, 1:]
        identity = torch.cat([photometric_error(sources[:, j], target, ssim) for j in range(sources.shape[1])], 1)
        return identity + 1e-5 * torch.randn_like(identity) if automask else identity


def self_supervised_loss(
    images: Tensor,
    K: Tensor,
    disparities: list[Tensor],
    T_source_target: Tensor,
    source_depths: Tensor | None = None,
    *,
    automask: bool = True,
    smoothness: float = 1e-3,
    geometry: float = 0.0,
    ssim: float = 0.85,
    min_depth: float = MIN_DEPTH,
    max_depth: float = MAX_DEPTH,
    identity: Tensor | None = None,
) -> LossOutput:
    """Total loss, averaged over the scales of ``disparities`` (each upsampled to full resolution).

    ``geometry`` > 0 needs ``source_depths`` (B, S-1, 1, H, W): it adds ``geometry x`` the masked mean depth
    inconsistency and weights the photometric errors by the self-discovered mask ``1 - inconsistency``
    (detached). ``smoothness`` weighs the edge-aware term at scale s by ``1 / 2^s``. The scale gauge on the
    finest depth is added with weight 1 (zero while the depth's scale is in the middle of its range).
    ``identity``: :func:`identity_errors` of ``images``, when the caller has them already (computed here if not).
    """
    B, S, _, H, W = images.shape
    target, sources = images[:, 0], images[:, 1:]
    if identity is None:
        identity = identity_errors(images, ssim, automask)
    use_geometry = geometry > 0
    if use_geometry and source_depths is None:
        raise ValueError("the geometry-consistency loss needs source_depths")
    zero = images.new_zeros(())
    sums = {"photometric": zero, "smoothness": zero, "geometry": zero, "used": zero}
    images_out = {}
    for s, disp in enumerate(disparities):
        full = disp if disp.shape[-2:] == (H, W) else F.interpolate(disp, (H, W), mode="bilinear", align_corners=False)
        depth = disp_to_depth(full, min_depth, max_depth)
        errors, geo = [], zero
        for j in range(S - 1):
            warp = inverse_warp(
                sources[:, j], depth, T_source_target[:, j], K, source_depths[:, j] if use_geometry else None
            )
            error = photometric_error(warp.image, target, ssim)
            if use_geometry:
                diff = depth_inconsistency(warp.depth, warp.source_depth)
                geo = geo + masked_mean(diff, warp.mask) / (S - 1)
                error = error * (1 - diff.detach())
            errors.append(error + INVALID * (1 - warp.mask))
            if s == 0 and j == 0:
                images_out.update(warped=warp.image.detach(), valid=warp.mask.detach())
        error, used = min_reprojection(torch.cat(errors, 1), identity, automask)
        small = F.interpolate(target, disp.shape[-2:], mode="area") if disp.shape[-2:] != (H, W) else target
        sums["photometric"] = sums["photometric"] + error.mean()
        sums["smoothness"] = sums["smoothness"] + edge_aware_smoothness(disp, small) / 2**s
        sums["geometry"] = sums["geometry"] + geo
        sums["used"] = sums["used"] + used.mean().detach()
        if s == 0:
            images_out["used"] = used.detach()
            gauge = scale_gauge(depth, min_depth, max_depth)
    n = len(disparities)
    terms = {k: v / n for k, v in sums.items()}
    terms["gauge"] = gauge
    total = terms["photometric"] + smoothness * terms["smoothness"] + geometry * terms["geometry"] + gauge
    if not use_geometry:
        del terms["geometry"]
    return LossOutput(total, terms, images_out)


class SelfSupervisedLoss(nn.Module):
    """:func:`self_supervised_loss` with its weights stored (``automask``, ``smoothness``, ``geometry``, ``ssim``)."""

    def __init__(self, automask: bool = True, smoothness: float = 1e-3, geometry: float = 0.0, ssim: float = 0.85):
        super().__init__()
        self.automask, self.smoothness, self.geometry, self.ssim = automask, smoothness, geometry, ssim

    def forward(
        self,
        images: Tensor,
        K: Tensor,
        disparities: list[Tensor],
        T_source_target: Tensor,
        source_depths: Tensor | None = None,
        identity: Tensor | None = None,
    ) -> LossOutput:
        return self_supervised_loss(
            images,
            K,
            disparities,
            T_source_target,
            source_depths,
            automask=self.automask,
            smoothness=self.smoothness,
            geometry=self.geometry,
            ssim=self.ssim,
            identity=identity,
        )
