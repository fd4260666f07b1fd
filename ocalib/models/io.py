"""Saving and loading ego-motion models: a slim file, or a Lightning checkpoint written by ``train/``.

Slim file (``torch.save``): ``{"kind": "ocalib-egomotion", "version": 1, "size", "height", "width",
"state_dict" (float32), "meta" (dict)}``.
"""

from __future__ import annotations

import pickle
from pathlib import Path

import torch

from ocalib.errors import InputError
from ocalib.models.egomotion import EgoMotionModel

KIND, VERSION = "ocalib-egomotion", 1
DEFAULT_CHECKPOINT = Path(__file__).parent / "weights" / "default.pt"
LIGHTNING_PREFIX = "model."  # the LightningModule holds the EgoMotionModel as ``self.model``


def save_model(model: EgoMotionModel, path, meta: dict | None = None) -> Path:
    """Write the slim model file (float32 state dict on CPU); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {
        k: (v.detach().float() if v.is_floating_point() else v.detach()).cpu().clone()
        for k, v in model.state_dict().items()
    }
    torch.save(
        {
            "kind": KIND,
            "version": VERSION,
            "size": model.size,
            "height": model.height,
            "width": model.width,
            "state_dict": state,
            "meta": dict(meta or {}),
        },
        path,
    )
    return path


def _build(path: Path, size, height, width, state: dict) -> EgoMotionModel:
    try:
        model = EgoMotionModel(size, int(height), int(width))
        model.load_state_dict(state)
    except (RuntimeError, InputError, TypeError, ValueError) as err:
        raise InputError(
            f"{path}: weights do not fit an ocalib ego-motion model ({str(err).splitlines()[0]})"
        ) from None
    return model.eval()


def load_model(path=None) -> EgoMotionModel:
    """Load a slim model file or a Lightning ``.ckpt`` from ``train/`` (None: :data:`DEFAULT_CHECKPOINT`).

    Returns the model in eval mode on CPU. A missing, corrupt or foreign file is an :class:`InputError`
    naming the file and what it is.
    """
    if path is None:
        path = DEFAULT_CHECKPOINT
        if not path.is_file():
            raise InputError(
                f"{path}: no default checkpoint shipped yet; train one with "
                "`ocalib train fit --config configs/train/synthetic-cpu.yaml` and pass --checkpoint "
                "<log dir>/model.pt"
            )
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: a folder, not a checkpoint file")
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint file")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - torch raises many kinds for a foreign or corrupt file
        if _is_text(path):
            kind = "a text file"
        elif isinstance(err, pickle.UnpicklingError):
            kind = "a corrupt file or another kind of file"
        else:
            kind = f"{type(err).__name__}: {(str(err).splitlines() or ['corrupt'])[0]}"
        raise InputError(f"{path}: not a readable torch checkpoint ({kind})") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: a torch file holding a {type(data).__name__}, not an ocalib ego-motion model")
    if data.get("kind") == KIND:
        if data.get("version") != VERSION:
            raise InputError(
                f"{path}: ocalib ego-motion model version {data.get('version')} (this ocalib reads {VERSION})"
            )
        return _build(path, data["size"], data["height"], data["width"], data["state_dict"])
    hp = data.get("hyper_parameters")
    if "pytorch-lightning_version" in data and isinstance(hp, dict) and {"size", "height", "width"} <= set(hp):
        n = len(LIGHTNING_PREFIX)
        state = {k[n:]: v for k, v in data["state_dict"].items() if k.startswith(LIGHTNING_PREFIX)}
        return _build(path, hp["size"], hp["height"], hp["width"], state)
    if "pytorch-lightning_version" in data:
        raise InputError(f"{path}: a Lightning checkpoint of another model, not an ocalib ego-motion checkpoint")
    what = f"kind {data['kind']!r}" if "kind" in data else f"keys {', '.join(sorted(map(str, data))[:6]) or 'none'}"
    raise InputError(f"{path}: a torch file of another kind ({what}), not an ocalib ego-motion model")


def _is_text(path: Path) -> bool:
    """Whether the file starts as text (UTF-8 without NUL bytes in its first KiB): a config or a note given where a
    checkpoint was expected."""
    head = path.read_bytes()[:1024]
    try:
        head.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return b"\0" not in head
