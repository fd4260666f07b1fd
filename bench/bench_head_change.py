"""The on-line head noticing a knocked camera on pose files, against following it by forgetting, in simulation.

Unit-baseline rigs on 1,000-frame LDS (hand-held) and car trajectories with pose noise (independent or drift);
camera 1 is turned by 2 deg and moved 5 cm at frame 500 (``knocked``), or not at all (``steady``). Per case:
the frames at which ``calibrate_rig`` detected the change and the first frame it named, the final rotation and
translation errors against the new extrinsic, beside the head without change detection (forgetting 1, and 0.99);
on the steady rigs the false alarms. Translation errors on cars are in the ground plane (the height is unobservable
from planar motion). Prints a table and writes ``bench/results/head_change.json``.

    python bench/bench_head_change.py [--seeds 10] [--noise 0.002]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from common import shown_path, write_json
from scipy.spatial.transform import Rotation

from ocalib.calib.drivers.change import ChangeTest
from ocalib.calib.drivers.sequence import calibrate_sequence
from ocalib.calib.poses.pipeline import RigPoses, calibrate_rig
from ocalib.io.poses import read_poses
from ocalib.sim.trajectory import add_noise, car_trajectory, knocked, lds_trajectory, random_rig, rig_trajectories

FRAMES, AT = 1000, 500
TRAJECTORIES = {"hand-held (LDS)": lds_trajectory, "car": car_trajectory}


def rig(seed: int, trajectory, model: str, noise: float, at: int, baseline: float = 1.0, knock=(2.0, 0.05)):
    """Poses (T, 2, 4, 4) and the final true ``T_cam0_cam1`` (4, 4) of one simulated rig."""
    g = torch.Generator().manual_seed(seed)
    cam0 = trajectory(FRAMES, g)
    extrinsics = knocked(random_rig(g, baseline), FRAMES, at, (0.0, knock[0], 0.0), (knock[1], 0.0, 0.0))
    return add_noise(rig_trajectories(cam0, extrinsics[:, None]), noise, g, model), extrinsics[-1].numpy()


def from_file(path: str):
    """A trajectory function ``(n, generator) -> (n, 4, 4)``: the first n poses of a pose file (KITTI, TUM or EuRoC,
    told apart as ``calibrate-poses`` does), re-referenced to the first."""
    poses = read_poses(path).poses
    poses = torch.from_numpy(np.linalg.inv(poses[:1]) @ poses)
    if len(poses) < FRAMES:
        raise SystemExit(f"{path}: {len(poses)} poses, fewer than the {FRAMES} a rig takes")
    return lambda n, generator: poses[:n]


def errors(R: np.ndarray, t: np.ndarray, truth: np.ndarray, planar: bool) -> tuple[float, float]:
    """Rotation error (deg) and translation error (units) of (R, t) against ``truth`` (4, 4); ``planar``: in the
    ground plane (camera 0's x-z), the height above it being unobservable from planar motion."""
    angle = np.linalg.norm(Rotation.from_matrix(R @ truth[:3, :3].T).as_rotvec())
    return float(np.degrees(angle)), float(np.linalg.norm((t - truth[:3, 3])[[0, 2] if planar else [0, 1, 2]]))


def run_case(
    seed: int,
    trajectory,
    model: str,
    noise: float,
    at: int,
    baseline: float = 1.0,
    knock=(2.0, 0.05),
    test: ChangeTest = ChangeTest(),
):
    poses, truth = rig(seed, trajectory, model, noise, at, baseline, knock)
    files = ["cam0.txt", "cam1.txt"]
    rig_poses = RigPoses(files, poses.numpy(), None, np.zeros((FRAMES, 2), int), [None] * 2, [None] * 2)
    run = calibrate_rig(rig_poses, change_test=test)
    out = {"seed": seed, "changes": [{k: c[k] for k in ("frame", "detected")} for c in run.changes]}
    planar = trajectory is car_trajectory  # a file's path is taken as it comes: its errors in 3-D
    out["detected"] = errors(run.final.rotation[0, 0].numpy(), run.final.translation[0, 0].numpy(), truth, planar)
    for forgetting in (1.0, 0.99):
        head = calibrate_sequence(poses, motion="multi", forgetting=forgetting)
        final = head.rotation[-1, 0].numpy(), head.translation[-1, 0].numpy()
        out[f"forgetting {forgetting:g}"] = errors(*final, truth, planar)
    return out


def summary(rows: list[dict]) -> dict:
    """Per noise model, over every trajectory: each knock's rigs noticed within 30 frames, and the steady rigs'
    alarms."""
    out = {}
    for row in rows:
        model = out.setdefault(row["noise_model"], {"knocks": {}, "steady_alarms": 0, "steady_rigs": 0})
        if row["case"] == "knocked":
            knock = model["knocks"].setdefault(
                f"{row['knock'][0]:g} deg {row['knock'][1]:g} m", {"within_30": 0, "rigs": 0}
            )
            knock["within_30"] += row["within_30"]
            knock["rigs"] += len(row["runs"])
        else:
            model["steady_alarms"] += row["alarms"]
            model["steady_rigs"] += len(row["runs"])
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10, help="rigs per trajectory, noise model and case")
    p.add_argument("--noise", type=float, default=0.002, help="pose noise (rad and units)")
    p.add_argument("--trajectory", nargs="+", help="camera 0's paths from pose files instead of the generators")
    p.add_argument("--baseline", type=float, default=1.0, help="camera 1's distance from camera 0 (the file's units)")
    p.add_argument("--knock", nargs=2, type=float, action="append", metavar=("DEG", "M"),
                   help="a knock's rotation and shift (default 2 deg, 0.05); repeat for several")  # fmt: skip
    p.add_argument("--gap", type=int, default=1, help="the change test's motions over this many frames")
    p.add_argument("--out", default="bench/results/head_change.json")
    args = p.parse_args()
    test = ChangeTest(gap=args.gap)
    knocks = [tuple(k) for k in args.knock] if args.knock else [(2.0, 0.05)]
    trajectories = (
        {f"{Path(f).parent.name}/{Path(f).stem}": from_file(f) for f in args.trajectory}
        if args.trajectory
        else TRAJECTORIES
    )
    rows = []
    header = (f"{'trajectory':16} {'noise':11} {'case (deg/m)':16} {'noticed':>8} {'<=30':>4} {'delay':>12} {'first frame':>12} "
              f"{'rot err: detect / f1 / f.99 (deg)':>34} {'t err: detect / f1 / f.99':>28}")  # fmt: skip
    print(header)
    for name, trajectory in trajectories.items():
        for model in ("independent", "drift"):
            for case, at, knock in [("knocked", AT, k) for k in knocks] + [("steady", FRAMES + 1, knocks[0])]:
                runs = [run_case(seed, trajectory, model, args.noise, at, args.baseline, knock, test)
                        for seed in range(args.seeds)]  # fmt: skip
                first = [r["changes"][0] for r in runs if r["changes"]]
                row = {"trajectory": name, "noise_model": model, "case": case, "runs": runs,
                       "noticed": len(first), "alarms": sum(len(r["changes"]) for r in runs)}  # fmt: skip
                if case == "knocked":
                    row["knock"] = list(knock)
                    row["within_30"] = sum(bool(r["changes"]) and r["changes"][0]["detected"] - AT <= 30
                                           and r["changes"][0]["frame"] >= AT - 10 for r in runs)  # fmt: skip
                    row["median_delay"] = float(np.median([c["detected"] - AT for c in first])) if first else None
                    row["max_delay"] = max((c["detected"] - AT for c in first), default=None)
                    row["max_frame_error"] = max((abs(c["frame"] - AT) for c in first), default=None)
                for key in ("detected", "forgetting 1", "forgetting 0.99"):
                    row[f"median_rotation_error_deg {key}"] = float(np.median([r[key][0] for r in runs]))
                    row[f"median_translation_error {key}"] = float(np.median([r[key][1] for r in runs]))
                rows.append(row)
                rot = " / ".join(f"{row[f'median_rotation_error_deg {k}']:.3f}" for k in ("detected", "forgetting 1",
                                                                                         "forgetting 0.99"))  # fmt: skip
                tr = " / ".join(f"{row[f'median_translation_error {k}']:.4f}" for k in ("detected", "forgetting 1",
                                                                                      "forgetting 0.99"))  # fmt: skip
                delay = (f"{row['median_delay']:.0f} (<={row['max_delay']})" if case == "knocked" and first
                         else "-")  # fmt: skip
                frame = f"+-{row['max_frame_error']}" if case == "knocked" and first else "-"
                label = f"{case} {knock[0]:g}/{knock[1]:g}" if case == "knocked" else case
                within = f"{row['within_30']:>3}" if case == "knocked" else "  -"
                print(f"{name:16} {model:11} {label:16} {row['noticed']:>3}/{args.seeds:<4} {within} {delay:>12} "
                      f"{frame:>12} {rot:>34} {tr:>28}", flush=True)  # fmt: skip
    write_json(args.out, {"frames": FRAMES, "change_at": AT, "noise": args.noise, "seeds": args.seeds,
                          "summary": summary(rows), "rows": rows,
                          "baseline": args.baseline, "knocks": knocks,
                          "trajectories": [shown_path(f) for f in args.trajectory or []]})  # fmt: skip


if __name__ == "__main__":
    main()
