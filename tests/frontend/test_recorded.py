"""RecordedFrontEnd: a second stream gets the recorded motions and then the front end's own, as one fresh run."""

import torch

from ocalib.frontend.base import FrontEnd
from ocalib.frontend.recorded import RecordedFrontEnd


class Counting(FrontEnd):
    """A front end with state: its motion moves along x by the number of frames it has seen, times the frame's value."""

    def reset(self) -> None:
        self.seen = 0

    def forward(self, frame, rig_rotation):
        self.seen += 1
        motion = torch.eye(4, dtype=torch.float64).expand(1, 2, 4, 4).clone()
        motion[..., 0, 3] = self.seen * frame
        return motion


def test_a_rewound_stream_equals_a_fresh_run():
    frames, rig = [0.5, 2.0, 3.0, 1.5, 4.0, 0.25], torch.eye(3).expand(1, 1, 3, 3)
    fresh = Counting()
    fresh.reset()
    expected = [fresh(f, rig) for f in frames]
    recorded = RecordedFrontEnd(Counting())
    recorded.reset()
    first = [recorded(f, rig) for f in frames[:4]]  # e.g. a trial over the first frames
    recorded.reset()  # the second stream: the four recorded, then on from frame 4
    second = [recorded(f, rig) for f in frames]
    for got, want in zip(first + second, expected[:4] + expected):
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    assert len(recorded.motions) == 4  # nothing recorded after the rewind: memory flat in the stream
    assert recorded.uses_rig_rotation  # a front end says nothing: taken as following the head
