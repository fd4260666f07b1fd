"""JSON has no NaN or infinity: such numbers become null."""

from __future__ import annotations

import math


def finite_or_null(x):
    """``x`` (numbers, nested dicts, lists and tuples) with every non-finite float as None."""
    if isinstance(x, dict):
        return {k: finite_or_null(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [finite_or_null(v) for v in x]
    return None if isinstance(x, float) and not math.isfinite(x) else x
