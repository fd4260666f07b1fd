"""``ocalib synth`` says, before rendering, when its trajectory hardly turns (the rotation between the cameras is
then unobservable from the motion), and says nothing for a route with turns."""

import math

import numpy as np
import pytest

from ocalib.synth.trajectory import turned_deg


def _yawing(degrees: list[float]) -> np.ndarray:
    """Poses (N, 4, 4) rotated about z by ``degrees`` from an arbitrary first orientation."""
    base = np.eye(4)
    base[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    out = []
    for d in degrees:
        c, s = math.cos(math.radians(d)), math.sin(math.radians(d))
        yaw = np.eye(4)
        yaw[:2, :2] = [[c, -s], [s, c]]
        out.append(yaw @ base)
    return np.stack(out)


def test_turned_is_the_largest_rotation_from_the_first_orientation():
    assert turned_deg(_yawing([0.0, 1.0, 3.0, 2.0, -1.5])) == pytest.approx(3.0)
    assert turned_deg(_yawing([10.0, 10.0])) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("seed, straight", [(1006, True), (0, False)])
def test_synth_notes_a_straight_route_before_rendering(seed, straight, tmp_path, monkeypatch, capsys):
    import ocalib.synth
    from ocalib.cli import main

    monkeypatch.setattr(ocalib.synth, "render_sequence", lambda *args, **kwargs: None)  # the note comes first
    assert main(["synth", "--preset", "front-left", "--seed", str(seed), "--out", str(tmp_path / "seq")]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "note:" in line]
    if straight:  # seed 1006's 300 frames drive straight on: 1.2 deg of pitch and roll from the road
        assert len(notes) == 1 and "turns at most 1.2 deg in these 300 frames" in notes[0], notes
        assert "not be observable" in notes[0]
    else:
        assert notes == []
