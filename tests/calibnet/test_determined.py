"""A reported extrinsic whose stated 1-sigma exceeds the targets' precision is said to be not determined; the on-line rig
estimator's, its translation loose, is reported (so flagged) rather than the head's, whose translation rests on monocular
scale; one the window never determined is not."""

from types import SimpleNamespace

import numpy as np
import pytest

from ocalib.calibnet.run import ImageCalibration, not_determined


def _entry(rotation_std, translation_std, translation=(1.0, 0.0, 1.0)):
    return {"rotation_std_deg": rotation_std, "translation_std": translation_std, "translation": list(translation)}


def test_a_car_with_its_height_alone_loose_is_determined():
    assert not_determined(_entry([0.1, 0.2, 0.1], [0.05, None, 0.08])) is None  # 0.1 of its 1.41 m: 0.141 m


@pytest.mark.parametrize(
    "entry, said",
    [
        (_entry([0.1, 0.6, 0.1], [0.01, 0.01, 0.01]), "rotation's 1-sigma is 0.60 deg"),
        (_entry([0.1, 0.1, 0.1], [0.05, None, 0.2]), "fewer than two translation axes"),
        (_entry([0.1, 0.1, 0.1], [0.01, 0.01, 0.01], (0.0, 0.0, 0.0)), "fewer than two translation axes"),
        (_entry(None, None), "no 1-sigma stated"),
        (_entry([None, 0.1, 0.1], [0.01, 0.01, 0.01]), "no 1-sigma stated"),
    ],
)
def test_an_extrinsic_over_the_targets_is_saidnot_determined(entry, said):
    assert said in not_determined(entry)


def _calibration(head: dict, loose: bool, waiting: bool = False) -> ImageCalibration:
    """A run whose head reported ``head`` for camera 1 and whose on-line rig estimator ended with a determined rotation
    and, where ``loose``, a translation whose 1-sigma leaves one axis within a tenth of its 1.41 m lever arm; where
    ``waiting``, the window never determined the camera."""
    estimate = {"camera": "cam1", "rotation": np.eye(3).tolist(), "quaternion_wxyz": [1.0, 0.0, 0.0, 0.0],
                "translation": [1.0, 0.0, 1.0], "rotation_std_deg": [0.1, 0.1, 0.1],
                "translation_std": [0.3, None, 0.05] if loose else [0.05, None, 0.05], "source": "rig_estimator"}  # fmt: skip
    run = SimpleNamespace(result_json=lambda: {"extrinsics": [dict(head, camera="cam1")], "warnings": []})
    rig = SimpleNamespace(
        result_json=lambda: {"extrinsics": [estimate]}, changes_json=lambda: [], warnings=[],
        undetermined=lambda: {1: "the window never determined it"} if waiting else {},
    )  # fmt: skip
    return ImageCalibration(run=run, errors=None, rig=rig)


HEAD = _entry([0.3, 0.3, 0.3], [0.05, 0.05, 0.05]) | {"source": None}  # the head's, its stated 1-sigma tight


@pytest.mark.parametrize(
    "loose, waiting, source, determined",
    [
        (False, False, "rig_estimator", True),
        (True, False, "rig_estimator", False),  # reported over the head's, flagged
        (True, True, None, True),  # never determined: the head's
    ],
)
def test_the_estimators_loose_translation_is_reported_flagged_and_an_undetermined_one_not(loose, waiting, source,
                                                                                          determined):  # fmt: skip
    doc = _calibration(HEAD, loose, waiting).result_json()
    entry = doc["extrinsics"][0]
    assert entry.get("source") == source and entry["determined"] == determined
    assert any("not reported" in w for w in doc["warnings"]) == (source is None)
    assert any("is not determined" in w for w in doc["warnings"]) == (not determined)
