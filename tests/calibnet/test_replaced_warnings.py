"""A warning that the on-line head's translation is not supported is said as the head's where a later stage's
result replaced it, and kept as it is where the head's result stands."""

from ocalib.calibnet.run import _replaced_said

WARNING = "cam1: the translation equations leave 27 % of camera 0's motion unexplained (RMS)"


def test_the_heads_warning_names_the_stage_that_replaced_its_translation():
    said = _replaced_said([WARNING, "cam1: other"], [{"camera": "cam1", "source": "rig_estimator"}])
    assert said == [
        f"on-line head: {WARNING}; its translation is replaced by the on-line rig estimator's",
        "cam1: other",
    ]
    assert _replaced_said([WARNING], [{"camera": "cam1"}]) == [WARNING]
    assert _replaced_said([WARNING], [{"camera": "cam2", "source": "bundle_adjustment"}]) == [WARNING]
