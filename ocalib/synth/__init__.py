"""``ocalib synth``: a procedural street-canyon world rendered by a multi-camera rig with exact ground truth.

* :func:`preset` / :func:`load_config` -> :class:`SynthConfig`
* :func:`render_rig` -> :class:`SynthSequence` (tensors in memory)
* :func:`render_sequence` -> the native rig layout on disk (see :mod:`ocalib.synth.writer`)
* :func:`render_view` renders one view of a :class:`World`

Convention: poses are camera-to-world 4x4 float64 (``p_world = R p_cam + t``), camera x right, y down,
z forward; world z up. ``T_cam0_cam`` is a camera's pose in camera 0's frame.
"""

from ocalib.synth.config import CameraConfig, SynthConfig, config_from_dict, load_config
from ocalib.synth.presets import PRESETS, preset
from ocalib.synth.render import WorldTensors, render_view
from ocalib.synth.sequence import SynthSequence, camera_poses, render_rig, render_sequence, rig_spec
from ocalib.synth.world import World, make_world

__all__ = [
    "CameraConfig",
    "PRESETS",
    "SynthConfig",
    "SynthSequence",
    "World",
    "WorldTensors",
    "camera_poses",
    "config_from_dict",
    "load_config",
    "make_world",
    "preset",
    "render_rig",
    "render_sequence",
    "render_view",
    "rig_spec",
]
