"""The on-line head's stages, each a pure function with its compiled numba twin beside it (``*_kernel.py``, equal to
1e-8): pose checks and gates, motion pairs, hand-eye rows, rotation, planar rotation, translation and scale, the
closed form, the joint refinement, and the small linear algebra under them."""
