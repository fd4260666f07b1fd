"""Depth error metrics of Eigen et al. with per-image median scaling (as SfMLearner and monodepth2 report them).

Convention: depth maps (H, W) float, metres for ground truth, any scale for predictions; ground-truth
pixels count when ``min_depth < gt < max_depth`` (0 = no surface). With median scaling the prediction is
multiplied by ``median(gt) / median(pred)`` over the valid pixels, then clipped to [min_depth, max_depth].
"""

from __future__ import annotations

import numpy as np

DEPTH_METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")


def depth_errors(pred: np.ndarray, gt: np.ndarray, min_depth: float = 1e-3, max_depth: float = 80.0,
                 median_scaling: bool = True) -> dict | None:
    """Metrics of one predicted depth map against ground truth, both (H, W) -> dict, or None when no pixel is valid.

    Keys: :data:`DEPTH_METRICS` (``a_k``: fraction of pixels with ``max(gt/pred, pred/gt) < 1.25^k``),
    ``scale`` (the median ratio applied, 1 without scaling) and ``valid`` (pixels used).
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape:
        raise ValueError(f"depth_errors: prediction {pred.shape} and ground truth {gt.shape} differ in shape")
    valid = (gt > min_depth) & (gt < max_depth) & np.isfinite(pred) & (pred > 0)
    if not valid.any():
        return None
    p, g = pred[valid], gt[valid]
    scale = float(np.median(g) / np.median(p)) if median_scaling else 1.0
    p = np.clip(p * scale, min_depth, max_depth)
    ratio = np.maximum(g / p, p / g)
    diff = g - p
    out = {
        "abs_rel": float(np.mean(np.abs(diff) / g)),
        "sq_rel": float(np.mean(diff**2 / g)),
        "rmse": float(np.sqrt(np.mean(diff**2))),
        "rmse_log": float(np.sqrt(np.mean((np.log(g) - np.log(p)) ** 2))),
    }
    for k in (1, 2, 3):
        out[f"a{k}"] = float(np.mean(ratio < 1.25**k))
    out["scale"] = scale
    out["valid"] = int(valid.sum())
    return out


def mean_depth_errors(per_image: list[dict | None]) -> dict:
    """Average per-image metrics (None entries, images without valid pixels, are skipped and counted).

    Returns :data:`DEPTH_METRICS` means, ``images`` (evaluated), ``skipped`` and the coefficient of
    variation of the median-scaling factors (``scale_cv``: how much the network's depth scale wanders).
    """
    used = [m for m in per_image if m is not None]
    out = {"images": len(used), "skipped": len(per_image) - len(used)}
    if not used:
        return out
    for key in DEPTH_METRICS:
        out[key] = float(np.mean([m[key] for m in used]))
    scales = np.array([m["scale"] for m in used])
    out["scale_cv"] = float(scales.std() / scales.mean())
    return out
