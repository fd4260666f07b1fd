"""The head's options: checked in one place, and the light list of motion pairings equals the head's own."""

import pytest

from ocalib.calib.drivers.options import MOTION_CHOICES, HeadOptions
from ocalib.calib.stages.pairing import MOTIONS
from ocalib.errors import InputError


def test_motion_choices_are_the_heads_pairings():
    assert set(MOTION_CHOICES) == set(MOTIONS)


@pytest.mark.parametrize(
    "options, message",
    [
        (HeadOptions(motion="foo"), "unknown motion 'foo'"),
        (HeadOptions(solver="foo"), "unknown solver 'foo'"),
        (HeadOptions(forgetting=0.0), r"forgetting must be in \(0, 1\]"),
        (HeadOptions(forgetting=1.5), r"forgetting must be in \(0, 1\]"),
        (HeadOptions(motion="absolute", solver="rls"), "has its own solver"),
        (HeadOptions(pose_error="camera"), "needs --motion absolute"),
        (HeadOptions(motion="absolute", pose_error="sky"), "unknown pose error 'sky'"),
    ],
)
def test_bad_head_options_are_one_error(options, message):
    with pytest.raises(InputError, match=message):
        options.checked()


def test_good_head_options_pass_unchanged():
    options = HeadOptions(motion="absolute", pose_error="world", forgetting=0.99)
    assert options.checked() is options
    assert HeadOptions().head_kwargs() == dict(motion="multi", solver="exact", forgetting=1.0, refine=True)
