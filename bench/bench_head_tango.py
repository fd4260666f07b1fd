"""The head's change test on real trajectories: three phones rigidly mounted together, each with its own
visual-inertial trajectory (the public ETH hand-eye calibration data, ``ethz-asl/hand_eye_calibration``,
``datasets/tango_triplet_{easy,hard}.zip``; their clocks minutes to hours apart).

Per recording and pair (CALIGULA-MARS, CALIGULA-NERO, MARS-NERO): ``calibrate-poses --time-offset auto`` as a user
runs it (the on-line head with its change test), the changes it declares (none happened), and the loop closure of
the three pairwise rotations ``R_CN^T R_CM R_MN`` (deg), beside a batch solve (``--solver batch``) of the same pairs;
and how far the two recordings' rotations are apart (the phones were mounted anew between them).

The data stay outside the repository: unzip both files and give their folder, which holds ``easy/*/`` and
``hard/*/`` with the three CSV files each (``time, x, y, z, qx, qy, qz, qw``; repeated stamps are dropped here, the
files round them to 10 ms at 33 Hz).

    python bench/bench_head_tango.py --root data/tango [--out bench/results/head_tango.json]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from common import write_json
from scipy.spatial.transform import Rotation

from ocalib.calib.poses.pipeline import HeadOptions, calibrate_files

PHONES = ("CALIGULA", "MARS", "NERO")
PAIRS = (("CALIGULA", "MARS"), ("CALIGULA", "NERO"), ("MARS", "NERO"))


def tum_files(folder: Path, out: Path) -> dict[str, Path]:
    """Each phone's CSV in ``folder`` as a TUM file under ``out`` (repeated stamps dropped)."""
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    for phone in PHONES:
        [csv] = folder.glob(f"{phone}_*.csv")
        rows = np.loadtxt(csv, delimiter=",")
        rows = rows[np.r_[True, np.diff(rows[:, 0]) > 0]]
        files[phone] = out / f"{phone}.tum"
        np.savetxt(files[phone], rows, fmt="%.6f")
    return files


def pair(files: dict[str, Path], a: str, b: str, solver: str) -> tuple[np.ndarray, list[dict]]:
    """Phone b's rotation in phone a's frame (3, 3) and the changes declared, by ``calibrate-poses``'s path."""
    run = calibrate_files([files[a], files[b]], HeadOptions(solver=solver), format="tum", time_offset=["auto"])
    doc = run.result_json()
    return np.array(doc["extrinsics"][0]["rotation"]), doc.get("changes", [])


def angle(R: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec())))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default="data/tango", help="the folder with easy/ and hard/ unzipped")
    p.add_argument("--out", default="bench/results/head_tango.json")
    args = p.parse_args()
    doc, rotations = {"recordings": {}}, {}
    print(f"{'recording':10} {'solver':7} {'changes C-M / C-N / M-N':25} {'loop (deg)':>10}")
    for name in ("easy", "hard"):
        [folder] = [d for d in (Path(args.root) / name).iterdir() if d.is_dir()]
        files = tum_files(folder, Path(args.root) / "tum" / name)
        for solver in ("exact", "batch"):
            found = {f"{a}-{b}": pair(files, a, b, solver) for a, b in PAIRS}
            R = {k: v[0] for k, v in found.items()}
            loop = angle(R["CALIGULA-NERO"].T @ R["CALIGULA-MARS"] @ R["MARS-NERO"])
            changes = {k: v[1] for k, v in found.items()}
            rotations[(name, solver)] = R
            declared = {k: len(v) for k, v in changes.items()}
            doc["recordings"].setdefault(name, {})[solver] = {
                "loop_deg": loop,
                "declared": declared,
                "changes": changes,
            }
            counts = " / ".join(str(len(c)) for c in changes.values())
            print(f"{name:10} {solver:7} {counts:25} {loop:10.3f}")
    for solver in ("exact", "batch"):
        apart = {k: angle(rotations[("easy", solver)][k].T @ rotations[("hard", solver)][k]) for k in R}
        doc.setdefault("recordings_apart_deg", {})[solver] = apart
        print(f"recordings apart ({solver}): " + ", ".join(f"{k} {v:.2f} deg" for k, v in apart.items()))
    write_json(args.out, doc)


if __name__ == "__main__":
    main()
