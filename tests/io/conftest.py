"""Fixtures of tests/io: a tiny generator of smooth synthetic rig trajectories."""

from __future__ import annotations

import pytest
from timed_rigs import make_rig


@pytest.fixture
def rig():
    """The synthetic rig generator, :func:`make_rig`."""
    return make_rig
