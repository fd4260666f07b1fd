"""Depth error metrics of Eigen et al. with per-image median scaling (as SfMLearner and monodepth2 report them).

Convention: depth maps (H, W) float, metres for ground truth, any scale for predictions; ground-truth
pixels count when ``min_depth < gt < max_depth`` (0 = no surface). With median scaling the prediction is
multiplied by ``median(gt) / median(pred)`` over the valid pixels, then clipped to [min_depth, max_depth].
"""

from __future__ import annotations

import numpy as np

DEPTH_METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")
DEPTH_RANGES = (5.0, 10.0, 20.0, 40.0)  # metres: inner edges of the ground-truth ranges of ``by_range``


def depth_errors(
    pred: np.ndarray, gt: np.ndarray, min_depth: float = 1e-3, max_depth: float = 80.0, median_scaling: bool = True
) -> dict | None:
    """Metrics of one predicted depth map against ground truth, both (H, W) -> dict, or None when no pixel is valid.

    Keys: :data:`DEPTH_METRICS` (``a_k``: fraction of pixels with ``max(gt/pred, pred/gt) < 1.25^k``),
    ``scale`` (the median ratio applied, 1 without scaling), ``valid`` (pixels used) and, per ground-truth range
    (edges :data:`DEPTH_RANGES`), the pixels and the sums of ``|p - g| / g`` and ``(p - g) / g``
    (``range_pixels``, ``range_abs_rel_sum``, ``range_signed_rel_sum``; pooled by :func:`mean_depth_errors`).
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
    bins = np.digitize(g, DEPTH_RANGES)
    out["range_pixels"] = np.bincount(bins, minlength=len(DEPTH_RANGES) + 1).tolist()
    out["range_abs_rel_sum"] = np.bincount(bins, np.abs(diff) / g, len(DEPTH_RANGES) + 1).tolist()
    out["range_signed_rel_sum"] = np.bincount(bins, -diff / g, len(DEPTH_RANGES) + 1).tolist()
    return out


def mean_depth_errors(per_image: list[dict | None]) -> dict:
    """Average per-image metrics (None entries, images without valid pixels, are skipped and counted).

    Returns :data:`DEPTH_METRICS` means, ``images`` (evaluated), ``skipped``, the coefficient of
    variation of the median-scaling factors (``scale_cv``: how much the network's depth scale wanders) and
    ``by_range``: per ground-truth range (:data:`DEPTH_RANGES`), its share of the pixels and their mean abs rel and
    signed relative error ``(p - g) / g``, pooled over the pixels of all images (a network that compresses the
    depth range is too far near the camera, > 0, and too near far from it, < 0).
    """
    used = [m for m in per_image if m is not None]
    out = {"images": len(used), "skipped": len(per_image) - len(used)}
    if not used:
        return out
    for key in DEPTH_METRICS:
        out[key] = float(np.mean([m[key] for m in used]))
    scales = np.array([m["scale"] for m in used])
    out["scale_cv"] = float(scales.std() / scales.mean())
    n, a, s = (np.sum([m[k] for m in used], 0) for k in ("range_pixels", "range_abs_rel_sum", "range_signed_rel_sum"))
    edges = (0.0, *DEPTH_RANGES, None)  # the last range is open (up to max_depth)
    out["by_range"] = [
        {
            "range_m": [lo, hi],
            "share": float(n[i] / n.sum()),
            "abs_rel": float(a[i] / n[i]),
            "signed_rel": float(s[i] / n[i]),
        }
        for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:]))
        if n[i] > 0
    ]
    return out
