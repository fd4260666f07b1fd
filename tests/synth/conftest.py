import pytest
import torch

from ocalib.synth import preset, render_rig

# The renderer's many small ops suffer badly from intra-op threads on a busy 2-core machine.
torch.set_num_threads(1)

SIZE = dict(height=64, width=208)


@pytest.fixture(scope="session")
def rendered():
    """Small in-memory renders of every preset, shared by the tests (rendered once)."""
    cache = {}

    def get(name, frames=5, **kw):
        key = (name, frames, tuple(sorted(kw.items())))
        if key not in cache:
            cache[key] = render_rig(preset(name).with_overrides(frames=frames, **{**SIZE, **kw}))
        return cache[key]

    return get
