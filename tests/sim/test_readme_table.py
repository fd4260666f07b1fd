"""The table of the paper's simulation in docs/simulation.md is what ``ocalib simulate`` gives: every cell, recomputed, within
5 % (medians over 20 rigs: well conditioned, but summed in another order on another CPU)."""

import re
from pathlib import Path

from ocalib.sim.experiment import simulate

PAGE = Path(__file__).resolve().parents[2] / "docs" / "simulation.md"
METHODS = {"paper RLS": "paper-rls", "paper RLS + 60-frame delay": "paper-rls-delay", "ocalib default": "default"}


def readme_table() -> dict[str, dict[float, float]]:
    """The table under ``<!-- ci: simulate table -->``: method -> noise -> median relative translation error."""
    text = PAGE.read_text().split("<!-- ci: simulate table -->", 1)[1].strip("\n")
    table = text.split("\n\n", 1)[0].splitlines()  # the table right after the marker, to its first blank line
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in table if line.startswith("|")]
    header, body = rows[0], [r for r in rows[2:] if re.fullmatch(r"[\d.]+", r[0])]
    return {METHODS[name]: {float(r[0]): float(r[i]) for r in body} for i, name in enumerate(header) if i}


def test_the_simulation_table_is_what_the_simulation_gives():
    table = readme_table()
    noise = sorted(next(iter(table.values())))
    assert len(table) == 3 and len(noise) == 5
    final = simulate(noise, 20, 128, "independent", "lds", list(table)).summary()["final"]
    for method, cells in table.items():
        for level, quoted in cells.items():
            got = final[method][str(level)]["translation_rel"]["median"]
            assert abs(got - quoted) <= 0.05 * quoted, f"{method} at noise {level}: {got:.4g}, the page {quoted}"
