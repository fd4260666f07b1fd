"""A front end's motions kept as it runs, to be given again.

:class:`RecordedFrontEnd`: ``calibrate --frontend auto`` runs each front end over the first frames to choose one;
the chosen one's motions over those frames are what a second run would compute again (where they do not depend on
the head: see :attr:`~ocalib.frontend.base.FrontEnd.uses_rig_rotation`), so the calibration stream takes them from
here and the front end goes on from the state it reached, each frame computed once.

:class:`EgoMotion` and :class:`ReplayedFrontEnd`: a whole run's motions kept in a file (``calibrate --ego-motion``)
and given again to a later run of the same frames, front end, head and code (:func:`ego_motion_fingerprint`), so
that another rig estimator or bundle adjustment runs without the front end. The result is the same to the last bit.

Convention: as :mod:`ocalib.frontend.base`.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset

from ocalib.data.sequence import Sequence
from ocalib.errors import InputError
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


# The package's code that makes a front end's motions (the head's estimate too: the network's motions follow it);
# a recording made by other code is not given again. Paths relative to the package, folders whole (the stream's
# functions of ocalib.calibnet.run are added by its caller, not the module: the result's reporting is not in it).
EGO_MOTION_CODE = ("frontend", "calib", "data", "geometry", "models", "losses", "eval", "io", "calibnet/net.py",
                   "errors.py")  # fmt: skip
EGO_MOTION_KIND = "ocalib ego-motion 1"  # a recording's header says it is one


@dataclass
class EgoMotion:
    """A run's ego-motion kept to be given again: ``motions`` (T, B, C, 4, 4) float64, what the front end returned
    frame by frame (:class:`~ocalib.frontend.base.FrontEnd`'s convention); ``settings`` what the result JSON records
    of the front end (with ``auto``, its choice); ``report`` its notes and warnings after the run (computed on the
    recorded run's final estimate); ``fingerprint`` what made it (:func:`ego_motion_fingerprint`)."""

    motions: np.ndarray
    settings: dict
    report: tuple[dict, list[str]]
    fingerprint: str

    def save(self, path: str | Path) -> None:
        header = {"kind": EGO_MOTION_KIND, "settings": self.settings, "report": list(self.report),
                  "fingerprint": self.fingerprint}  # fmt: skip
        with open(path, "wb") as f:  # np.savez would add ".npz" to a name without it
            np.savez(f, motions=self.motions, header=np.array(json.dumps(header, default=_plain)))

    @classmethod
    def load(cls, path: str | Path) -> EgoMotion:
        """The recording at ``path``; an :class:`InputError` naming it where it is not one."""
        try:
            with np.load(path, allow_pickle=False) as z:
                header, motions = json.loads(str(z["header"])), z["motions"]
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as e:
            raise InputError(f"{path}: not an ego-motion recording of ocalib calibrate ({e})") from None
        entries = header if isinstance(header, dict) else {}
        report, settings, fingerprint = entries.get("report"), entries.get("settings"), entries.get("fingerprint")
        if not (entries.get("kind") == EGO_MOTION_KIND and motions.ndim == 5 and isinstance(settings, dict)
                and isinstance(fingerprint, str) and isinstance(report, list) and len(report) == 2):  # fmt: skip
            raise InputError(f"{path}: not an ego-motion recording of ocalib calibrate")
        return cls(motions, settings, tuple(report), fingerprint)


def _plain(x):
    """A numpy value as the JSON of its Python equivalent."""
    if isinstance(x, np.ndarray | np.generic):
        return x.tolist()
    raise TypeError(f"{type(x).__name__} is not JSON serialisable")


def ego_motion_fingerprint(run: dict, checkpoint: str | None) -> str:
    """The SHA-256 of what a run's ego-motion depends on: ``run`` (the sequence, its frames and cameras, the front
    end's and the head's settings, as JSON), the versions of the libraries that compute it, the package's
    :data:`EGO_MOTION_CODE` and the network's ``checkpoint`` file (None: the shipped one)."""
    import cv2
    import scipy

    from ocalib.models import DEFAULT_CHECKPOINT

    versions = {
        "numpy": np.__version__,
        "torch": torch.__version__,
        "opencv": cv2.__version__,
        "scipy": scipy.__version__,
    }
    digest = hashlib.sha256(json.dumps([run, versions], sort_keys=True, default=str).encode())
    root = Path(__file__).resolve().parents[1]
    for part in EGO_MOTION_CODE:
        for file in sorted((root / part).rglob("*.py")) if (root / part).is_dir() else [root / part]:
            digest.update(file.relative_to(root).as_posix().encode() + file.read_bytes())
    weights = Path(checkpoint) if checkpoint else DEFAULT_CHECKPOINT
    if weights.is_file():
        digest.update(weights.read_bytes())
    return digest.hexdigest()


class ReplayedFrontEnd(FrontEnd):
    """The front end of a recorded run (:class:`EgoMotion`): frame t's motion is the recording's, whatever the images
    and the head's estimate; its report is the recording's."""

    uses_rig_rotation = False

    def __init__(self, recording: EgoMotion):
        super().__init__()
        self.recording = recording

    def frames(self, sequence: Sequence):
        return _Indices(len(self.recording.motions))

    def reset(self) -> None:
        pass

    def forward(self, frame, rig_rotation: Tensor) -> Tensor:
        return torch.from_numpy(self.recording.motions[int(frame)]).to(rig_rotation.device)

    def report(self, names: list[str], frames: int, estimate) -> tuple[dict, list[str]]:
        return self.recording.report


class _Indices(Dataset):
    """Item t is t: the frames of a :class:`ReplayedFrontEnd` (no image is read)."""

    def __init__(self, n: int):
        self.n = n

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, t: int) -> int:
        return t
