"""The head's change test on real trajectories: three phones rigidly mounted together, each with its own
visual-inertial trajectory (the public ETH hand-eye calibration data, ``ethz-asl/hand_eye_calibration``,
``datasets/tango_triplet_{easy,hard}.zip``; their clocks minutes to hours apart).

Per recording and pair (CALIGULA-MARS, CALIGULA-NERO, MARS-NERO): ``calibrate-poses --time-offset auto`` as a user
runs it (the on-line head with its change test), the changes it declares (none happened), and the loop closure of
the three pairwise rotations ``R_CN^T R_CM R_MN`` (deg), beside a batch solve (``--solver batch``) of the same pairs;
and how far the two recordings' rotations are apart (the phones were mounted anew between them). Per pair too, how
the trajectories' errors accumulate: the spread of the hand-eye residuals over 30 frames over that of consecutive
frames, under the final estimate (about 1 where each pose's error is its own, 5.5 for a random walk).

The data stay outside the repository: unzip both files and give their folder, which holds ``easy/*/`` and
``hard/*/`` with the three CSV files each (``time, x, y, z, qx, qy, qz, qw``; repeated stamps are dropped here, the
files round them to 10 ms at 33 Hz).

    python bench/bench_head_tango.py --root data/tango [--gap 1] [--out bench/results/head_tango.json]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from common import write_json
from scipy.spatial.transform import Rotation

from ocalib.calib.drivers.change import ChangeTest, handeye_residuals, motions
from ocalib.calib.poses.pipeline import HeadOptions, calibrate_rig, load_rig

PHONES = ("CALIGULA", "MARS", "NERO")
PAIRS = (("CALIGULA", "MARS"), ("CALIGULA", "NERO"), ("MARS", "NERO"))
ACCUMULATION_GAP = 30  # frames


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


def pair(files: dict[str, Path], a: str, b: str, solver: str, test: ChangeTest) -> tuple[np.ndarray, list[dict], float]:
    """Phone b's rotation in phone a's frame (3, 3), the changes declared, by ``calibrate-poses``'s path with the
    change test ``test``, and how the pose errors accumulate over ``ACCUMULATION_GAP`` frames
    (:func:`accumulation`)."""
    rig = load_rig([files[a], files[b]], format="tum", time_offset=["auto"])
    run = calibrate_rig(rig, HeadOptions(solver=solver), change_test=test)
    doc = run.result_json()
    final = run.final
    R, t, s = final.rotation[0, 0].numpy(), final.translation[0, 0].numpy(), float(final.scale[0, 0])
    poses = rig.poses[rig.valid.all(1)]
    return np.array(doc["extrinsics"][0]["rotation"]), doc.get("changes", []), accumulation(poses, R, t, s)


def accumulation(poses: np.ndarray, R: np.ndarray, t: np.ndarray, s: float, gap: int = ACCUMULATION_GAP) -> float:
    """The spread of the hand-eye residuals of motions over ``gap`` frames over that of consecutive frames' motions
    (median absolute deviations, per residual axis, their median), under the extrinsic (R, t, s); poses (T, 2, 4, 4).
    About 1 where each pose's error is its own, sqrt(gap) where the errors add up frame after frame (a random walk)."""
    spread = []
    for g in (1, gap):
        A, B = motions(poses[:, 0], g)[g:], motions(poses[:, 1], g)[g:]
        n = len(A)
        r = handeye_residuals(A, B, np.broadcast_to(R, (n, 3, 3)), np.broadcast_to(t, (n, 3)), np.full(n, s))[0]
        spread.append(np.median(np.abs(r - np.median(r, 0)), 0))
    return float(np.median(spread[1] / spread[0]))


def angle(R: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec())))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default="data/tango", help="the folder with easy/ and hard/ unzipped")
    p.add_argument("--gap", type=int, default=1, help="the change test's motions over this many frames")
    p.add_argument("--out", default="bench/results/head_tango.json")
    args = p.parse_args()
    test = ChangeTest(gap=args.gap)
    doc, rotations = {"recordings": {}}, {}
    print(f"{'recording':10} {'solver':7} {'changes C-M / C-N / M-N':25} {'loop (deg)':>10} "
          f"{'errors over ' + str(ACCUMULATION_GAP) + ' frames / 1':>26}")  # fmt: skip
    for name in ("easy", "hard"):
        [folder] = [d for d in (Path(args.root) / name).iterdir() if d.is_dir()]
        files = tum_files(folder, Path(args.root) / "tum" / name)
        for solver in ("exact", "batch"):
            found = {f"{a}-{b}": pair(files, a, b, solver, test) for a, b in PAIRS}
            R = {k: v[0] for k, v in found.items()}
            loop = angle(R["CALIGULA-NERO"].T @ R["CALIGULA-MARS"] @ R["MARS-NERO"])
            changes = {k: v[1] for k, v in found.items()}
            rotations[(name, solver)] = R
            declared = {k: len(v) for k, v in changes.items()}
            doc["recordings"].setdefault(name, {})[solver] = {
                "loop_deg": loop,
                "declared": declared,
                "changes": changes,
                "accumulation": {k: v[2] for k, v in found.items()},
            }
            counts = " / ".join(str(len(c)) for c in changes.values())
            spread = " / ".join(f"{v[2]:.1f}" for v in found.values())
            print(f"{name:10} {solver:7} {counts:25} {loop:10.3f} {spread:>26}")
    for solver in ("exact", "batch"):
        apart = {k: angle(rotations[("easy", solver)][k].T @ rotations[("hard", solver)][k]) for k in R}
        doc.setdefault("recordings_apart_deg", {})[solver] = apart
        print(f"recordings apart ({solver}): " + ", ".join(f"{k} {v:.2f} deg" for k, v in apart.items()))
    write_json(args.out, doc | {"gap": args.gap, "accumulation_gap": ACCUMULATION_GAP})


if __name__ == "__main__":
    main()
