"""Symmetric eigen-decomposition with gradients that stay finite when eigenvalues repeat.

``torch.linalg.eigh`` (and ``svd``) back-propagate through ``1 / (lambda_i - lambda_j)``, which is
infinite for repeated eigenvalues -- exactly what planar motion produces (two zero singular values).
:func:`guarded_eigh` replaces that factor by ``d / (d^2 + eps^2)`` (Lorentzian broadening), equal to
``1 / d`` up to a relative ``(eps / d)^2`` for well-separated eigenvalues and bounded by
``1 / (2 eps)`` otherwise. The compiled twin (cyclic Jacobi) is in :mod:`ocalib.calib.stages.linalg_kernel`.
"""

from __future__ import annotations

import torch
from torch import Tensor

BROADENING = 1e-9  # relative to the largest |eigenvalue|


class _GuardedEigh(torch.autograd.Function):
    @staticmethod
    def forward(ctx, M: Tensor):
        evals, evecs = torch.linalg.eigh(M)
        ctx.save_for_backward(evals, evecs)
        return evals, evecs

    @staticmethod
    def backward(ctx, g_evals: Tensor, g_evecs: Tensor):
        evals, evecs = ctx.saved_tensors
        d = evals.unsqueeze(-2) - evals.unsqueeze(-1)  # d[i, j] = lambda_j - lambda_i
        eps = (BROADENING * evals.abs().amax(-1, keepdim=True).unsqueeze(-1)).clamp_min(1e-100)  # eps^2 > 0
        F = d / (d * d + eps * eps)
        inner = torch.diag_embed(g_evals) + F * (evecs.mT @ g_evecs)
        grad = evecs @ inner @ evecs.mT
        return (grad + grad.mT) / 2


def guarded_eigh(M: Tensor) -> tuple[Tensor, Tensor]:
    """Eigen-decomposition of symmetric ``M`` (..., n, n): eigenvalues ascending (..., n), eigenvectors
    as columns (..., n, n); gradients finite for repeated eigenvalues (see module docstring)."""
    if torch.is_grad_enabled() and M.requires_grad:
        return _GuardedEigh.apply(M)
    return torch.linalg.eigh(M)
