"""Non-finite numbers become null, at any depth, and the result is strict JSON."""

import json
import math

from ocalib.io.jsonable import finite_or_null


def test_non_finite_numbers_become_null_at_any_depth():
    doc = {"a": math.nan, "b": [1.0, math.inf, {"c": -math.inf, "d": (2, math.nan)}], "e": "nan", "f": None, "g": 3}
    out = finite_or_null(doc)
    assert out == {"a": None, "b": [1.0, None, {"c": None, "d": [2, None]}], "e": "nan", "f": None, "g": 3}
    assert json.loads(json.dumps(out, allow_nan=False)) == out  # raises on any NaN or inf left
