"""The front-end interface: one synchronised frame of every camera in, each camera's motion out.

Convention: the motion of camera c at frame t is ``T_prev_cur`` (B, C, 4, 4) float64, the pose of frame t's camera
in frame t-1's camera frame (``p_prev = R p_cur + t``), the identity at the first frame; each camera's translation
in units of its own (a monocular front end's).
"""

from __future__ import annotations

from torch import Tensor, nn
from torch.utils.data import Dataset

from ocalib.data.sequence import Sequence


class FrontEnd(nn.Module):
    """A stream of rig frames -> every camera's frame-to-frame motion.

    Subclasses implement :meth:`for_sequence` (build one for a sequence's cameras), :meth:`frames` (the dataset of
    what :meth:`forward` takes, frame by frame), :meth:`reset` and :meth:`forward`; :meth:`report` is optional.
    """

    uses_rig_rotation: bool = True  # whether forward's motions depend on its rig_rotation (the head's estimate)

    @classmethod
    def for_sequence(cls, sequence: Sequence, options, device: str = "cpu") -> FrontEnd:
        """The front end for ``sequence``'s cameras (``options``: :class:`~ocalib.frontend.FrontEndOptions`)."""
        raise NotImplementedError

    def frames(self, sequence: Sequence) -> Dataset:
        """Item t: frame t of every camera as :meth:`forward` takes it (read in DataLoader workers)."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forget the stream: the next frame is every camera's first."""
        raise NotImplementedError

    def forward(self, frame, rig_rotation: Tensor) -> Tensor:
        """Consume one frame -> motions (B, C, 4, 4) float64. ``rig_rotation`` (B, C - 1, 3, 3): the calibration's
        current rotation ``R_cam0_camk`` (the identity before its first estimate), for front ends that use the rig."""
        raise NotImplementedError

    def report(self, names: list[str], frames: int, estimate) -> tuple[dict, list[str]]:
        """After a stream of ``frames`` frames of cameras ``names``: settings for the result JSON and warnings
        (``estimate``: the last :class:`~ocalib.calib.drivers.result.Calibration`, None where no head ran)."""
        return {}, []
