"""Options shared by the commands: the head's (``calibrate-poses``, ``calibrate``) and the front end's
(``calibrate``, ``demo``), each added to a parser once and read back as a typed object.

Light on purpose (no torch): every command's parser is built for ``ocalib --help``.
"""

from __future__ import annotations

import argparse

from ocalib.calib.drivers.options import REFINE_CHOICES, HeadOptions
from ocalib.frontend import AUTO, AUTO_FRAMES, FRONTENDS, FrontEndOptions

# the head's motion pairings (the keys of ocalib.calib.drivers.options.MOTION_CHOICES) -> what they are
MOTIONS_HELP = {
    "multi": "gaps of 1, 2, 4, 8 and 16 frames weighted by their noise (default, for VO / SLAM trajectories)",
    "first": "every frame against frame 0",
    "consecutive": "consecutive frames",
}


def add_head_arguments(p: argparse.ArgumentParser, refine: str, motions: dict[str, str], solvers: dict[str, str]):
    """The head's options: ``--motion`` (``motions``: choice -> help), ``--solver`` (likewise), ``--forgetting``
    and ``--refine`` (default ``refine``)."""
    p.add_argument("--motion", choices=motions, default="multi", help="motion pairs: " + "; ".join(
        f"{name}: {text}" for name, text in motions.items()))  # fmt: skip
    p.add_argument("--solver", choices=solvers, default="exact", help="; ".join(
        f"{name}: {text}" for name, text in solvers.items()))  # fmt: skip
    p.add_argument(
        "--forgetting",
        type=float,
        default=1.0,
        metavar="L",
        help="forgetting factor in (0, 1]: old frames weigh L per frame (default 1)",
    )
    p.add_argument(
        "--refine",
        choices=REFINE_CHOICES,
        default=refine,
        help="joint refinement of the closed form by the translation rows: always (for SLAM or metric poses), only "
        "where the rotation rows leave the rotation unobservable (for a monocular front end, whose translation "
        f"directions are biased and would pull an observable rotation off), or never; default {refine}",
    )


def head_options(args: argparse.Namespace) -> HeadOptions:
    """The :class:`HeadOptions` of parsed arguments (:func:`add_head_arguments`), checked."""
    pose_error = getattr(args, "pose_error", None)
    return HeadOptions(args.motion, args.solver, args.forgetting, REFINE_CHOICES[args.refine], pose_error).checked()


def add_frontend_arguments(p: argparse.ArgumentParser, network_options: bool = True) -> None:
    """``--frontend`` (the registry's), ``--checkpoint``, and with ``network_options`` the network's ``--scale``,
    ``--align`` and ``--rig-align``."""
    p.add_argument(
        "--frontend",
        choices=[*FRONTENDS, AUTO],
        default=AUTO,
        help="ego-motion front end: " + "; ".join(f"{name}: {kind.help}" for name, kind in FRONTENDS.items())
        + f"; {AUTO} (default): each tried on the first {AUTO_FRAMES} frames, the one whose cameras turn by the most "
        "nearly equal angles every frame (as a rigid rig's must) kept; the network where a network option "
        "(--checkpoint, --scale, --align, --rig-align) is given",
    )  # fmt: skip
    p.add_argument(
        "--checkpoint", metavar="CKPT", help="ego-motion model (ocalib model file or training .ckpt; default: shipped)"
    )
    if not network_options:
        return
    p.add_argument(
        "--scale",
        choices=("head", "normalise"),
        default="normalise",
        help="network scale: normalise each camera's steps by their running mean length over ~100 "
        "frames (default: measured better on the held-out rigs, docs/calibnet.md), or trust it per camera "
        "and let the head solve the ratio (head)",
    )
    p.add_argument(
        "--align",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="refine each network motion by direct photometric alignment on the network's depth (default "
        "with the network front end: more accurate on every held-out rig, docs/results-calibrate.md; "
        "most of the time a frame takes)",
    )
    p.add_argument(
        "--rig-align",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="with --align, re-align each camera k's translation with its rotation held to the rig's "
        "(camera 0's rotation through the current extrinsic) and the depth's tilt solved with it "
        "(default with --align: measured better on the held-out cars, docs/results-calibrate.md)",
    )


def frontend_options(args: argparse.Namespace) -> FrontEndOptions:
    """The :class:`FrontEndOptions` of parsed arguments (:func:`add_frontend_arguments`), checked."""
    extra = {name: getattr(args, name) for name in ("scale", "align", "rig_align") if hasattr(args, name)}
    return FrontEndOptions(args.frontend, args.checkpoint, **extra).resolved()
