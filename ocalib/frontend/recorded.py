"""A front end whose motions are kept as it runs, to be given again to a second stream that then runs on live.

``calibrate --frontend auto`` runs each front end over the first frames to choose one; the chosen one's motions
over those frames are what a second run would compute again (where they do not depend on the head: see
:attr:`~ocalib.frontend.base.FrontEnd.uses_rig_rotation`), so the calibration stream takes them from here and
the front end goes on from the state it reached, each frame computed once.

Convention: as :mod:`ocalib.frontend.base`.
"""

from __future__ import annotations

from torch import Tensor

from ocalib.data.sequence import Sequence
from ocalib.frontend.base import FrontEnd


class RecordedFrontEnd(FrontEnd):
    """``front_end`` with its motions recorded until a rewind. The first :meth:`reset` resets it; a later one rewinds
    to the first recorded frame: the frames recorded are given back, then ``front_end`` runs on from where it
    stopped, recording no more (its state never rewinds: a stream after a rewind must be the recorded frames
    followed by the next ones)."""

    def __init__(self, front_end: FrontEnd):
        super().__init__()
        self.front_end, self.motions, self._next, self._recording = front_end, [], 0, True

    @property
    def uses_rig_rotation(self) -> bool:
        return self.front_end.uses_rig_rotation

    def frames(self, sequence: Sequence):
        return self.front_end.frames(sequence)

    def reset(self) -> None:
        if self.motions:
            self._recording = False
        else:
            self.front_end.reset()
        self._next = 0

    def forward(self, frame, rig_rotation: Tensor) -> Tensor:
        if self._next < len(self.motions):
            motion = self.motions[self._next]
        else:
            motion = self.front_end(frame, rig_rotation)
            if self._recording:
                self.motions.append(motion)
        self._next += 1
        return motion

    def report(self, names: list[str], frames: int, estimate) -> tuple[dict, list[str]]:
        return self.front_end.report(names, frames, estimate)
