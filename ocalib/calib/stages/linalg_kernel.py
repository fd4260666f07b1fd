"""Compiled twins (numba) of the small linear algebra of :mod:`ocalib.calib.stages.linalg` and of the quaternion
functions of :mod:`ocalib.geometry.quaternion`, for the head's compiled kernel (:mod:`ocalib.calib.drivers.kernel`).

Small symmetric eigenproblems are solved by cyclic Jacobi (eigenvalues ascending, as ``torch.linalg.eigh``), small
general systems by LU with partial pivoting. Where an eigenvalue is repeated the eigenvectors differ from LAPACK's by
a rotation within the repeated space, and any eigenvector may differ in sign.

Every twin works on one entry (no batch dimension) and writes its results into arrays the caller passes (the kernel
allocates them once per thread, not per call); ``n`` is the size of the block of a larger array that is used.
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import shutil
import tempfile
from pathlib import Path

import numba
from numba import njit

JACOBI_SWEEPS = 30
JACOBI_TOLERANCE = 1e-16  # an off-diagonal entry below this times sqrt(a_pp a_qq) is treated as zero

# Every compiled twin (cached on disk by :func:`compiled`): no GIL (the rigs run on numba's threads), numpy's division
# semantics, and floating-point contraction and reassociation allowed (an FMA or a reordered sum changes results by
# rounding only).
OPTIONS = dict(nogil=True, error_model="numpy", fastmath={"contract", "reassoc"})

_STAGES = Path(__file__).resolve().parent
_FRAME_KERNEL = _STAGES.parent / "drivers" / "kernel.py"  # the head's compiled frame update


def kernel_sources() -> list[Path]:
    """The kernel modules (the stages' ``*_kernel.py``, the drivers' ``kernel.py``) and the PyTorch modules beside
    them (their twins, whose constants they compile in)."""
    kernels = sorted(_STAGES.glob("*_kernel.py"))
    twins = [_STAGES / p.name.replace("_kernel.py", ".py") for p in kernels]
    return [p for p in [*kernels, *twins, _FRAME_KERNEL] if p.exists()]


@functools.cache
def cache_dir() -> str | None:
    """numba's cache folder for the kernels, one per digest of :func:`kernel_sources`: a compiled function holds the
    twins it calls from other files, which numba's own check (the function's file alone) would miss. Under
    ``NUMBA_CACHE_DIR`` where set, else in this package's ``__pycache__`` (older digests' folders removed), else in
    the user's cache folder: the first that is writable; None where none is (nothing is cached)."""
    digest = hashlib.sha256(b"".join(p.name.encode() + p.read_bytes() for p in kernel_sources())).hexdigest()[:16]
    user = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ocalib" / f"numba-{digest}"
    in_tree = _STAGES / "__pycache__" / f"numba-{digest}"
    chosen = [Path(numba.config.CACHE_DIR) / f"ocalib-{digest}"] if numba.config.CACHE_DIR else []
    for folder in [*chosen, in_tree, user]:
        if _writable(folder):
            if folder == in_tree:
                for old in folder.parent.glob("numba-*"):
                    if old != folder:
                        shutil.rmtree(old, ignore_errors=True)
            return str(folder)
    return None


def _writable(folder: Path) -> bool:
    """Whether ``folder`` exists (made where missing) and a file can be written in it."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


def compiled(**options):
    """numba's ``njit`` with :data:`OPTIONS` and ``options``, cached in :func:`cache_dir` (numba's ``CACHE_DIR`` set
    while the function is decorated, when numba picks its cache folder)."""

    def decorate(function):
        folder, previous = cache_dir(), numba.config.CACHE_DIR
        numba.config.CACHE_DIR = folder or previous
        try:
            return njit(cache=folder is not None, **OPTIONS, **options)(function)
        finally:
            numba.config.CACHE_DIR = previous

    return decorate


jit = compiled()
# The helpers called for every rig with named tuples of many arrays: compiled into their callers (numba inlines them),
# since a call counts a reference to each array it is passed, about 5 ns each (atomics: more across threads).
jit_inline = compiled(inline="always")


@jit
def eigh(A, n, w, V, a):
    """:func:`~ocalib.calib.stages.linalg.guarded_eigh` of the symmetric n x n block of ``A``: ``w`` ascending, ``V``
    its eigenvectors as columns (both written), ``a`` scratch (n x n at least)."""
    _start(A, n, V, a)
    for _ in range(JACOBI_SWEEPS):
        rotated = False
        for p in range(n):
            for q in range(p + 1, n):
                c, s, t = _rotation(a, p, q)
                if s != 0.0:
                    _rotate(a, V, p, q, c, s, t, n)
                    rotated = True
        if not rotated:
            break
    _sort(w, V, a, n)


@jit
def eigh4(A, w, V, a):
    """:func:`eigh` of a 4x4 matrix, in rounds of two disjoint rotations ((0, 1) and (2, 3), then (0, 2) and (1, 3),
    then (0, 3) and (1, 2)): the two of a round are independent, so their square roots and divisions overlap (a
    rotation's cost is their latency)."""
    _start(A, 4, V, a)
    for _ in range(JACOBI_SWEEPS):
        rotated = False
        for r in range(3):
            p1, q1, p2, q2 = (0, 1, 2, 3) if r == 0 else ((0, 2, 1, 3) if r == 1 else (0, 3, 1, 2))
            c1, s1, t1 = _rotation(a, p1, q1)
            c2, s2, t2 = _rotation(a, p2, q2)
            if s1 != 0.0:
                _rotate(a, V, p1, q1, c1, s1, t1, 4)
                rotated = True
            if s2 != 0.0:
                _rotate(a, V, p2, q2, c2, s2, t2, 4)
                rotated = True
        if not rotated:
            break
    _sort(w, V, a, 4)


@jit
def _start(A, n, V, a):
    """Jacobi's start: ``a`` the n x n block of ``A``, ``V`` the identity."""
    for i in range(n):
        for j in range(n):
            a[i, j] = A[i, j]
            V[i, j] = 1.0 if i == j else 0.0


@jit
def _rotation(a, p, q):
    """Jacobi rotation ``(c, s, t)`` that zeroes ``a[p, q]``; ``(1, 0, 0)`` where it is negligible (it moves no
    eigenvalue by more than its rounding: relative accuracy, as LAPACK's)."""
    apq = a[p, q]
    if apq * apq <= JACOBI_TOLERANCE * JACOBI_TOLERANCE * abs(a[p, p] * a[q, q]):
        return 1.0, 0.0, 0.0
    theta = (a[q, q] - a[p, p]) / (2.0 * apq)
    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
    if theta < 0.0:
        t = -t
    c = 1.0 / math.sqrt(t * t + 1.0)
    return c, t * c, t


@jit
def _rotate(a, V, p, q, c, s, t, n):
    """Apply the rotation of :func:`_rotation` to the symmetric ``a`` and the eigenvectors ``V``."""
    apq = a[p, q]
    a[p, p] -= t * apq
    a[q, q] += t * apq
    a[p, q] = a[q, p] = 0.0
    for r in range(n):
        if r != p and r != q:
            arp, arq = a[r, p], a[r, q]
            a[r, p] = a[p, r] = c * arp - s * arq
            a[r, q] = a[q, r] = s * arp + c * arq
    for k in range(n):
        vkp, vkq = V[k, p], V[k, q]
        V[k, p], V[k, q] = c * vkp - s * vkq, s * vkp + c * vkq


@jit
def _sort(w, V, a, n):
    """Eigenvalues ``w`` from the diagonal of ``a``, ascending, with the columns of ``V`` (insertion sort, stable)."""
    for i in range(n):
        w[i] = a[i, i]
    for i in range(1, n):
        j = i
        while j > 0 and w[j - 1] > w[j]:
            w[j - 1], w[j] = w[j], w[j - 1]
            for k in range(n):
                V[k, j - 1], V[k, j] = V[k, j], V[k, j - 1]
            j -= 1


@jit
def lu_solve(H, b, n, x):
    """``x`` with ``H x = b`` (n x n) by LU with partial pivoting (``torch.linalg.solve``); ``H`` and ``b`` are
    overwritten."""
    for j in range(n):
        p = j
        for i in range(j + 1, n):
            if abs(H[i, j]) > abs(H[p, j]):
                p = i
        if p != j:
            for k in range(n):
                H[j, k], H[p, k] = H[p, k], H[j, k]
            b[j], b[p] = b[p], b[j]
        for i in range(j + 1, n):
            f = H[i, j] / H[j, j]
            for k in range(j + 1, n):
                H[i, k] -= f * H[j, k]
            b[i] -= f * b[j]
    for i in range(n - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, n):
            s -= H[i, k] * x[k]
        x[i] = s / H[i, i]


@jit
def quaternion_to_rotation_matrix(q, R):
    """:func:`~ocalib.geometry.quaternion.quaternion_to_rotation_matrix`: ``R`` (3x3) of ``q`` (any norm > 0)."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    w, x, y, z = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    R[0, 0] = w * w + x * x - y * y - z * z
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = w * w - x * x + y * y - z * z
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = w * w - x * x - y * y + z * z


@jit
def rotation_matrix_to_quaternion(R, q):
    """:func:`~ocalib.geometry.quaternion.rotation_matrix_to_quaternion` (Shepperd's method, w >= 0): ``q`` of the
    3x3 block of ``R``."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = (R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1], R[1, 2],
                                                   R[2, 0], R[2, 1], R[2, 2])  # fmt: skip
    d0, d1, d2, d3 = 1 + r00 + r11 + r22, 1 + r00 - r11 - r22, 1 - r00 + r11 - r22, 1 - r00 - r11 + r22
    best = d0
    pivot = 0
    if d1 > best:
        best, pivot = d1, 1
    if d2 > best:
        best, pivot = d2, 2
    if d3 > best:
        pivot = 3
    if pivot == 0:
        a, b, c, d = d0, r21 - r12, r02 - r20, r10 - r01
    elif pivot == 1:
        a, b, c, d = r21 - r12, d1, r01 + r10, r02 + r20
    elif pivot == 2:
        a, b, c, d = r02 - r20, r01 + r10, d2, r12 + r21
    else:
        a, b, c, d = r10 - r01, r02 + r20, r12 + r21, d3
    n = math.sqrt(a * a + b * b + c * c + d * d)
    if a < 0:
        n = -n
    q[0], q[1], q[2], q[3] = a / n, b / n, c / n, d / n


@jit
def left_product_matrix(q, L):
    """:func:`~ocalib.geometry.quaternion.left_product_matrix`: ``L`` (4x4) with ``q * p = L(q) p``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    L[0, 0], L[0, 1], L[0, 2], L[0, 3] = w, -x, -y, -z
    L[1, 0], L[1, 1], L[1, 2], L[1, 3] = x, w, -z, y
    L[2, 0], L[2, 1], L[2, 2], L[2, 3] = y, z, w, -x
    L[3, 0], L[3, 1], L[3, 2], L[3, 3] = z, -y, x, w
