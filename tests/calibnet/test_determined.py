"""A reported extrinsic whose stated 1-sigma exceeds the targets' precision is said to be not determined."""

import pytest

from ocalib.calibnet.run import not_determined


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
