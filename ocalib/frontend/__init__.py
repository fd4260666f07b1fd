"""Ego-motion front ends: one synchronised frame of every camera in, each camera's motion out.

A front end is a :class:`~ocalib.frontend.base.FrontEnd`; :data:`FRONTENDS` lists them (the command line's
choices, ``calibrate``, ``demo`` and the benchmarks read it) and :func:`build_frontend` makes one for a
sequence. Adding a front end: a module with a ``FrontEnd`` subclass and one line here. By default (:data:`AUTO`)
``calibrate`` tries every registered front end on the sequence's first frames and keeps the one whose cameras'
rotations best fit a rigid rig.

This module stays light (no torch): the command line reads it for its ``--help``.

Convention: a front end's motion is ``T_prev_cur`` (the pose of the current frame in the previous frame's
camera frame), each camera in units of its own.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

from ocalib.errors import InputError

if TYPE_CHECKING:
    from ocalib.data.sequence import Sequence
    from ocalib.frontend.base import FrontEnd


@dataclass(frozen=True)
class FrontEndKind:
    """A registered front end: where its class lives (``module:Class``) and what it is, in one line."""

    path: str
    help: str


# name -> front end
FRONTENDS: dict[str, FrontEndKind] = {
    "network": FrontEndKind(
        "ocalib.frontend.network:NetworkFrontEnd",
        "the pose network of a checkpoint, its motions refined by photometric alignment on its depth",
    ),
    "opencv": FrontEndKind(
        "ocalib.frontend.opencv:OpenCVFrontEnd",
        "OpenCV monocular VO per camera (KLT tracks, essential matrix, windowed bundle adjustment)",
    ),
}
SCALE_MODES = ("head", "normalise")
AUTO = "auto"  # not a front end: each of FRONTENDS tried, one kept (ocalib.calibnet.run.choose_frontend)
AUTO_FRAMES = 100  # the frames each front end runs on where AUTO chooses


@dataclass(frozen=True)
class FrontEndOptions:
    """How ``calibrate`` makes its front end.

    name: a key of :data:`FRONTENDS`, or :data:`AUTO` (the default: chosen per sequence by ``calibrate``, the
    network where any of its options is given). The network's: ``checkpoint`` (None: the shipped one), ``scale``
    (see :class:`~ocalib.frontend.network.NetworkFrontEnd`), ``align`` and ``rig_align`` (None: on with the network,
    measured better on the held-out rigs: docs/results-calibrate.md).
    """

    name: str = AUTO
    checkpoint: str | None = None
    scale: str = "normalise"
    align: bool | None = None
    rig_align: bool | None = None

    def resolved(self) -> FrontEndOptions:
        """These options checked, with ``align`` and ``rig_align`` decided; an :class:`InputError` where they
        contradict each other."""
        if self.name not in FRONTENDS and self.name != AUTO:
            raise InputError(f"unknown front end {self.name!r}: {', '.join([*FRONTENDS, AUTO])}")
        if self.scale not in SCALE_MODES:
            raise InputError(f"unknown scale mode {self.scale!r}: {', '.join(SCALE_MODES)}")
        if self.name == AUTO:
            if self.checkpoint is None and self.align is None and self.rig_align is None and self.scale == "normalise":
                return self  # align and rig_align are decided with the front end chosen
            return replace(self, name="network").resolved()  # a network option given: the network it is
        network = self.name == "network"
        align = network if self.align is None else self.align
        if align and not network:
            raise InputError(
                "align refines the pose network's motions; the OpenCV front end has its own bundle adjustment"
            )
        rig_align = align if self.rig_align is None else self.rig_align
        if rig_align and not align:
            raise InputError("rig-align re-aligns the photometrically aligned motions: it needs align")
        return replace(self, align=align, rig_align=rig_align)

    def settings(self) -> dict:
        """What the result JSON records of the front end."""
        network = self.name == "network"
        return {
            "frontend": self.name,
            "checkpoint": str(self.checkpoint or "default") if network else None,
            "align": self.align,
            "rig_align": self.rig_align,
            "scale": self.scale if network else None,
        }


def frontend_class(name: str) -> type[FrontEnd]:
    """The class of the registered front end ``name``."""
    module, _, cls = FRONTENDS[name].path.partition(":")
    return getattr(importlib.import_module(module), cls)


def build_frontend(sequence: Sequence, options: FrontEndOptions, device: str = "cpu") -> FrontEnd:
    """The front end of ``options`` for ``sequence``'s cameras, on ``device``."""
    options = options.resolved()
    return frontend_class(options.name).for_sequence(sequence, options, device)
