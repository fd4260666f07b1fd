"""The calibration head's settings, as the command line and the library pass them around.

Convention: as :mod:`ocalib.calib.drivers.online` (``T_cam0_camk``; camera 0 the reference).
"""

from __future__ import annotations

from dataclasses import dataclass

from ocalib.errors import InputError

MOTION_CHOICES = ("first", "consecutive", "multi")  # the keys of ocalib.calib.stages.pairing.MOTIONS (a light copy)
SOLVERS = ("exact", "rls", "batch")
POSE_ERRORS = ("camera", "world")
REFINE_CHOICES = {"unobservable": "unobservable", "always": True, "never": False}  # words -> ``refine``


@dataclass(frozen=True)
class HeadOptions:
    """How the head solves: ``motion`` (:data:`MOTION_CHOICES` or ``absolute``, every pose on its own), ``solver``
    (:data:`SOLVERS`; ``batch``: one solve of all frames, pose files only), ``forgetting`` in (0, 1], ``refine``
    (True, False or ``"unobservable"``, see :data:`~ocalib.calib.stages.solve.REFINE_MODES`), and with ``absolute``
    ``pose_error`` (:data:`POSE_ERRORS`: where the poses' translation error lives)."""

    motion: str = "multi"
    solver: str = "exact"
    forgetting: float = 1.0
    refine: bool | str = True
    pose_error: str | None = None

    def checked(self, solvers: tuple[str, ...] = SOLVERS) -> HeadOptions:
        """These options, or an :class:`InputError` naming what is wrong (``solvers``: those the caller has)."""
        if self.motion not in MOTION_CHOICES + ("absolute",):
            raise InputError(f"unknown motion {self.motion!r}: {', '.join(MOTION_CHOICES + ('absolute',))}")
        if self.solver not in solvers:
            raise InputError(f"unknown solver {self.solver!r}: {', '.join(solvers)}")
        if not 0 < self.forgetting <= 1:
            raise InputError(f"forgetting must be in (0, 1], got {self.forgetting}")
        if self.motion == "absolute" and self.solver != "exact":
            raise InputError(
                f"motion 'absolute' has its own solver (on-line AX = YB); leave --solver at exact, not {self.solver!r}"
            )
        if self.pose_error is not None and self.motion != "absolute":
            raise InputError(f"--pose-error describes absolute poses; it needs --motion absolute, not {self.motion!r}")
        if self.pose_error is not None and self.pose_error not in POSE_ERRORS:
            raise InputError(f"unknown pose error {self.pose_error!r}: {', '.join(POSE_ERRORS)}")
        return self

    def head_kwargs(self) -> dict:
        """The keyword arguments of :class:`~ocalib.calib.drivers.online.OnlineCalibrator`."""
        return dict(motion=self.motion, solver=self.solver, forgetting=self.forgetting, refine=self.refine)

    def settings(self) -> dict:
        """What the result JSON records of the head."""
        return dict(motion=self.motion, solver=self.solver, forgetting=self.forgetting, refine=self.refine)
