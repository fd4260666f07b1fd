"""Rigid-body geometry: the conventions in code.

numpy, no torch: :mod:`~ocalib.geometry.se3` (SO(3) exp and log, rotation angles, poses, perturbations),
:mod:`~ocalib.geometry.alignment` (Umeyama's Sim(3) fit), :mod:`~ocalib.geometry.directions` (angles between and
projectors without directions), :mod:`~ocalib.geometry.angles` (quaternions as people read them). torch (batched,
differentiable, any dtype and device): :mod:`~ocalib.geometry.pose` and :mod:`~ocalib.geometry.quaternion`, whose
names this package hands on, each loaded on first use so that importing a numpy module here loads no torch.
"""

from importlib import import_module

_TORCH = {
    "pose": ("invert_pose", "make_pose", "orthonormality_error", "relative_pose", "rereference"),
    "quaternion": (
        "canonical_quaternion",
        "left_product_matrix",
        "quaternion_angle",
        "quaternion_conjugate",
        "quaternion_multiply",
        "quaternion_to_rotation_matrix",
        "right_product_matrix",
        "rotation_angle",
        "rotation_matrix_to_quaternion",
        "so3_exp",
    ),
}
_MODULE = {name: module for module, names in _TORCH.items() for name in names}

__all__ = sorted(_MODULE)


def __getattr__(name: str):
    if name not in _MODULE:
        raise AttributeError(f"module 'ocalib.geometry' has no attribute {name!r}")
    return getattr(import_module(f"ocalib.geometry.{_MODULE[name]}"), name)


def __dir__():
    return sorted(set(globals()) | set(_MODULE))
