"""Constant tensors (bases of linear maps) built once per dtype and device."""

from __future__ import annotations

from functools import cache, wraps

import torch


def constant_cache(make):
    """Cache ``make(dtype, device) -> tensors`` per (dtype, device).

    The tensors are made outside inference mode (a cached inference tensor could not be used by autograd
    later). Under ``torch.compile`` ``make`` is traced instead: Dynamo would ignore the cache (and warn), and the
    compiler folds the result into constants.
    """

    @cache
    def cached(dtype: torch.dtype, device: torch.device):
        with torch.inference_mode(False):
            return make(dtype, device)

    @wraps(make)
    def get(dtype: torch.dtype, device: torch.device):
        return make(dtype, device) if torch.compiler.is_compiling() else cached(dtype, device)

    return get
