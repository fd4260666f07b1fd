"""Small, batched, differentiable rigid-body geometry in torch (any dtype, any device)."""

from ocalib.geometry.pose import (
    invert_pose,
    make_pose,
    orthonormality_error,
    relative_pose,
    rereference,
)
from ocalib.geometry.quaternion import (
    canonical_quaternion,
    left_product_matrix,
    quaternion_angle,
    quaternion_conjugate,
    quaternion_multiply,
    quaternion_to_rotation_matrix,
    right_product_matrix,
    rotation_angle,
    rotation_matrix_to_quaternion,
)

__all__ = [
    "canonical_quaternion",
    "invert_pose",
    "left_product_matrix",
    "make_pose",
    "orthonormality_error",
    "quaternion_angle",
    "quaternion_conjugate",
    "quaternion_multiply",
    "quaternion_to_rotation_matrix",
    "relative_pose",
    "rereference",
    "right_product_matrix",
    "rotation_angle",
    "rotation_matrix_to_quaternion",
]
