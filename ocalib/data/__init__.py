"""Datasets: the native rig layout and loaders for real sequence layouts.

``open_sequence(path)`` detects the layout (rig, KITTI raw, KITTI odometry, SfMLearner, image folder) and
returns a :class:`Sequence`; :class:`SnippetDataset` gives training snippets and :class:`RigStream` a
synchronised multi-camera stream. Names are imported lazily so that ``ocalib.data.rig`` stays light.
"""

from importlib import import_module

_EXPORTS = {
    "Camera": "sequence",
    "Sequence": "sequence",
    "open_sequence": "layout",
    "find_sequences": "layout",
    "detect_layout": "layout",
    "SnippetDataset": "snippets",
    "collate_snippets": "snippets",
    "RigStream": "stream",
    "SnippetAugmentation": "augment",
    "read_image": "image_io",
    "read_depth": "image_io",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(import_module(f"ocalib.data.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'ocalib.data' has no attribute {name!r}")
