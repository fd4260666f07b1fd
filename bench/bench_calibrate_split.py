"""``ocalib calibrate`` as a user runs it, on a fixed test split of rendered rigs never used while developing: the
share of rigs within the targets at the end, and within them or said to be not determined by the result itself
(Wilson 95 % intervals), medians and 90th percentiles of the errors, the
on-line rig estimator's normalised estimation error squared (NEES) against the chi-square band (and its rotation's
alone, with the rotation errors' mean per axis of camera 0's frame: a bias the rigs share), and knocks found.

Each rig is rendered once under ``--root`` (outside git) and calibrated by ``ocalib calibrate --sequence DIR
--metric-trajectory CAM0/poses.txt`` (its front end chosen as by default), with ``--no-bundle-adjust`` (mode
``online``), that and ``--metric-noise 0`` (mode ``online-exact``: the user says the trajectory is exact, as a
render's is, and the estimator holds it) or a noise of 1 cm or 1 mm (``online-1cm``, ``online-1mm``: the poses
still solved, the positions priors of that noise) or with the defaults (mode ``default``); each run's JSON is kept under
``ROOT/runs/MODE/`` and reused, so the split is filled over several sittings. Knocked rigs (``NAME-knocked``: camera
1 turned by 2 deg at mid-stream, cars also moved 5 cm) give the detection rate and delay; every change reported on a
steady rig is a false alarm.
Each rig's ego-motion is kept under ``ROOT/runs/ego-motion/`` (``calibrate --ego-motion``): a run whose front end,
head and their code are those of the recording takes its motions from there (the same JSON, without the front end's
time: both modes and every later run of the rig estimator share one front-end run).

    python bench/bench_calibrate_split.py --split test --modes online [--presets front-left handheld] [--limit N]
    python bench/bench_calibrate_split.py --split test --summary-only      # the table from the runs kept

The ``dev`` split (seeds 6001..) may be tuned on; the ``test`` split (seeds 7001..) is only measured.
Targets: cars 0.5 deg, 5 deg of direction in the ground plane, 0.1 baselines; hand-held 0.5 deg, 10 deg, 0.25.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from bench_calibnet_accuracy import ensure
from bench_rig_online import TARGETS, ensure_knocked
from common import write_json
from scipy.stats import chi2, norm

from ocalib.calibnet.run import not_determined
from ocalib.data.layout import open_sequence
from ocalib.geometry.se3 import innovation
from ocalib.rigba.change import UNINFORMED

SPLITS = {"dev": 6001, "test": 7001}  # the first seed of each split
COUNTS = {"handheld": 20, "front-left": 20, "surround": 10}  # rigs per preset
KNOCKED = 10  # of the first presets' rigs, knocked too
FRAMES = 300
DETECT_WITHIN = 30  # frames after the knock a change must be noticed in
MODES = {
    "online": ["--no-bundle-adjust"],
    "online-1cm": ["--no-bundle-adjust", "--metric-noise", "0.01"],
    "online-1mm": ["--no-bundle-adjust", "--metric-noise", "0.001"],
    "online-exact": ["--no-bundle-adjust", "--metric-noise", "0"],
    "default": [],
}


def rigs(split: str, presets: list[str]) -> list[tuple[str, bool]]:
    """(name, knocked) of the split: per preset ``COUNTS`` steady rigs, the hand-held and car ones ``KNOCKED`` times
    knocked too; steady first, preset by preset."""
    first = SPLITS[split]
    steady = [(f"{p}-{first + i}", False) for p in presets for i in range(COUNTS[p])]
    knocks = [(f"{p}-{first + i}", True) for p in presets if p != "surround" for i in range(KNOCKED)]
    return steady + knocks


def run(root: Path, name: str, knocked: bool, mode: str) -> dict:
    """The result JSON of ``ocalib calibrate`` on the rig (rendered and run where missing), with the seconds it
    took (``bench_seconds``)."""
    out = root / "runs" / mode / f"{name}{'-knocked' * knocked}.json"
    if out.exists():
        return json.loads(out.read_text())
    path = ensure_knocked(root, name, FRAMES) if knocked else ensure(root, name, FRAMES)
    cam0 = open_sequence(path).cameras[0].name
    ego_motion = root / "runs" / "ego-motion" / f"{name}{'-knocked' * knocked}.npz"
    ego_motion.parent.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, "-m", "ocalib", "calibrate", "--sequence", str(path), "--metric-trajectory",
               str(path / cam0 / "poses.txt"), "--out", str(out.with_suffix(".tmp")), "--ego-motion",
               str(ego_motion)]  # fmt: skip
    command += MODES[mode]
    out.parent.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{name}: ocalib calibrate failed ({done.returncode}): {done.stderr.strip()[-500:]}")
    doc = json.loads(out.with_suffix(".tmp").read_text()) | {"bench_seconds": time.perf_counter() - start}
    out.write_text(json.dumps(doc))
    out.with_suffix(".tmp").unlink()
    return doc


def within(e: dict, kind: str) -> bool:
    """Whether one camera's reported errors are within ``kind``'s targets (an undefined figure is not)."""
    rotation, direction, relative = TARGETS[kind]
    values = [e.get("rotation_error_deg"), e.get("translation_direction_error_deg"),
              e.get("translation_error_rel_baseline")]  # fmt: skip
    return all(v is not None and math.isfinite(v) for v in values) and (
        values[0] <= rotation and values[1] <= direction and values[2] <= relative
    )


def rig_within(doc: dict, kind: str) -> bool:
    """Whether every camera's reported extrinsic of the run ``doc`` is within ``kind``'s targets."""
    return all(within(e, kind) for e in doc.get("ground_truth_errors", [{}]))


def estimator_errors(doc: dict, path: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per camera the estimator's final error ``e`` (6,) against the truth after any knock
    (:func:`ocalib.rigba.change.innovation`: rotation rad, translation m, camera 0's axes) and its stated covariance
    ``P`` (6, 6); none where the estimator stated none."""
    cams = open_sequence(path).cameras
    out = []
    for k, estimate in enumerate(doc.get("rig_estimator", {}).get("extrinsics", []), start=1):
        if estimate.get("covariance") is None:
            continue
        truth = cams[k].change.T_cam0_cam if cams[k].change is not None else cams[k].T_cam0_cam
        truth = np.linalg.inv(cams[0].T_cam0_cam) @ truth
        E = np.eye(4)
        E[:3, :3], E[:3, 3] = estimate["rotation"], estimate["translation"]
        out.append((innovation(E, truth), np.array(estimate["covariance"])))
    return out


def nees(doc: dict, path: Path) -> list[tuple[float, int]]:
    """Per camera the estimator's final ``(e^T P^-1 e, d)`` (:func:`estimator_errors`), ``P`` restricted to the ``d``
    directions it informs (variance under ``UNINFORMED / 10``)."""
    out = []
    for e, P in estimator_errors(doc, path):
        lam, V = np.linalg.eigh((P + P.T) / 2)
        keep = lam < UNINFORMED / 10
        d = V[:, keep].T @ e
        out.append((float(d @ (d / lam[keep])), int(keep.sum())))
    return out


def rotation_errors(docs: dict[str, dict], root: Path) -> dict:
    """Over the runs ``docs`` (name -> JSON), the estimator's final rotation errors (deg) about camera 0's axes of the
    cameras it placed (every rotation 1-sigma under 1 deg): their mean and spread per axis (a bias shared by the
    rigs shows as a mean beyond its spread over the square root of their number), and the rotation's own NEES per
    degree of freedom (its 3x3 block of the covariance), and the same of the errors less their mean (what the
    covariance holds of them once the shared bias is taken out)."""
    errors, covariances = [], []
    for name, doc in docs.items():
        for e, P in estimator_errors(doc, root / name):
            if np.all(np.sqrt(np.clip(np.diag(P)[:3], 0, None)) < np.radians(1.0)):
                errors.append(e[:3])
                covariances.append(P[:3, :3])
    if not errors:
        return {}
    errors = np.array(errors)

    def per_dof(e: np.ndarray) -> float:  # the NEES of errors e (N, 3) per degree of freedom
        return float(np.mean([x @ np.linalg.solve(P, x) for x, P in zip(e, covariances)]) / 3)

    spread = np.degrees(errors.std(0, ddof=1)).tolist() if len(errors) > 1 else None
    return {"cameras": len(errors), "mean_deg": np.degrees(errors.mean(0)).tolist(), "sd_deg": spread,
            "nees_per_dof": per_dof(errors), "nees_per_dof_less_mean": per_dof(errors - errors.mean(0))}  # fmt: skip


def wilson(successes: int, n: int) -> tuple[float, float]:
    """The Wilson score 95 % interval of a rate."""
    if n == 0:
        return (math.nan, math.nan)
    z = norm.ppf(0.975)
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (centre - half, centre + half)


def summarise(root: Path, docs: dict[tuple[str, bool], dict]) -> dict:
    """Per preset the rates, error quantiles, NEES and knocks of the runs ``docs`` ((name, knocked) -> JSON)."""
    out = {}
    for preset in dict.fromkeys(name.rsplit("-", 1)[0] for name, _ in docs):
        kind = "handheld" if preset == "handheld" else "car"
        steady = {n: d for (n, k), d in docs.items() if not k and n.startswith(preset + "-")}
        cameras = [e for d in steady.values() for e in d.get("ground_truth_errors", [])]
        rig_ok = [rig_within(d, kind) for d in steady.values()]
        # said: a reported extrinsic the result itself calls not determined (its 1-sigma over the targets)
        said = [any(not_determined(x) is not None for x in d["extrinsics"]) for d in steady.values()]
        right_or_said = [ok or s for ok, s in zip(rig_ok, said)]
        wrong_unsaid = len(rig_ok) - sum(right_or_said)
        sources = [e.get("source") for d in steady.values() for e in d["extrinsics"]]
        stats = {
            "rigs": len(steady),
            "within": int(sum(rig_ok)),
            "within_interval": wilson(sum(rig_ok), len(rig_ok)),
            "within_or_said": int(sum(right_or_said)),
            "within_or_said_interval": wilson(sum(right_or_said), len(rig_ok)),
            "said": int(sum(said)),
            "off_unsaid": wrong_unsaid,
        }
        for key in ("rotation_error_deg", "translation_direction_error_deg", "translation_error_rel_baseline"):
            v = np.array([np.nan if e.get(key) is None else e[key] for e in cameras], float)
            stats[key] = {"median": float(np.nanmedian(v)) if len(v) else None,
                          "p90": float(np.nanpercentile(v, 90)) if len(v) else None,
                          "undefined": int(np.isnan(v).sum())}  # fmt: skip
        stats["sources"] = {s: sources.count(s) for s in set(sources)}
        terms = [t for n, d in steady.items() for t in nees(d, root / n)]
        if terms:
            total, dof = sum(t for t, _ in terms), sum(d for _, d in terms)
            stats["nees_per_dof"] = total / dof
            stats["nees_band"] = (chi2.ppf(0.025, dof) / dof, chi2.ppf(0.975, dof) / dof)
            stats["nees_cameras"] = len(terms)
            stats["rotation_errors"] = rotation_errors(steady, root)
        frames = sum(d["settings"]["frames"] for d in steady.values())
        alarms = sum(len(d.get("changes", [])) for d in steady.values())
        stats["false_alarms"], stats["steady_frames"] = alarms, frames
        knocked = {n: d for (n, k), d in docs.items() if k and n.startswith(preset + "-")}
        if knocked:
            delays, determined = [], []
            for d in knocked.values():
                found = [c["detected"] - FRAMES // 2 for c in d.get("changes", []) if c["frame"] >= FRAMES // 2 - 4]
                delays.append(min(found) if found else math.inf)
                determined.append(determined_before_knock(d, bool(found)))
            hit = sum(x <= DETECT_WITHIN for x in delays)
            finite = [x for x in delays if math.isfinite(x)]
            stats["knocks"] = {
                "rigs": len(delays),
                "detected_within": hit,
                "interval": wilson(hit, len(delays)),
                # of the rigs whose knocked camera the estimator had determined before the knock (None: not recorded)
                "determined_before": None if None in determined else sum(determined),
                "detected_within_of_determined": sum(x <= DETECT_WITHIN for x, k in zip(delays, determined) if k),
                "delay_median": float(np.median(finite)) if finite else None,
                "delay_p90": float(np.percentile(finite, 90)) if finite else None,
                # the reported extrinsics at the end within the targets of the new mounting, or said not determined
                "within_at_end": sum(rig_within(d, kind) for d in knocked.values()),
                "within_or_said_at_end": sum(
                    rig_within(d, kind) or any(not_determined(x) is not None for x in d["extrinsics"])
                    for d in knocked.values()
                ),
                "false_alarms_before": sum(
                    c["frame"] < FRAMES // 2 - 4 for d in knocked.values() for c in d.get("changes", [])
                ),
            }
        out[preset] = stats
    return out


def rig_row(root: Path, name: str, knocked: bool, doc: dict) -> dict:
    """One run's outcome, to compare runs rig by rig: within the targets, said not determined, each camera's errors
    and the source of its reported extrinsic, the changes declared, the estimator's NEES terms and releases."""
    kind = "handheld" if name.startswith("handheld-") else "car"
    errors = doc.get("ground_truth_errors", [])
    keys = ("rotation_error_deg", "translation_direction_error_deg", "translation_error_rel_baseline")
    return {
        "rig": f"{name}{'-knocked' * knocked}",
        "within": all(within(e, kind) for e in errors or [{}]),
        "said": any(not_determined(x) is not None for x in doc["extrinsics"]),
        "errors": [{k: e.get(k) for k in keys} for e in errors],
        "sources": [x.get("source") for x in doc["extrinsics"]],
        "changes": [
            {k: c[k] for k in ("frame", "detected", "rotation_change_deg", "translation_change")}
            for c in doc.get("changes", [])
        ],
        "nees": nees(doc, root / f"{name}{'-knocked' * knocked}"),
        "released_at": [x.get("released_at_frame") for x in doc.get("rig_estimator", {}).get("extrinsics", [])],
    }


def determined_before_knock(doc: dict, changed: bool) -> bool | None:
    """Whether the estimator had determined the knocked camera (camera 1) before the knock at ``FRAMES // 2``: it
    declared a change of it there (``changed``: it was tracking it), or released it before; None where the run
    does not record its release (or the estimator never ran)."""
    cameras = doc.get("rig_estimator", {}).get("extrinsics", [])
    if changed:
        return True
    if not cameras or "released_at_frame" not in cameras[0]:
        return None
    released = cameras[0]["released_at_frame"]
    return released is not None and released < FRAMES // 2


def table(summary: dict, mode: str) -> str:
    lines = [f"mode {mode}: rigs within the targets (Wilson 95 %), errors median / p90, NEES per dof [band]"]
    for preset, s in summary.items():
        lo, hi = s["within_interval"]
        line = f"  {preset:11s} {s['within']:2d}/{s['rigs']:2d} [{lo:.2f}, {hi:.2f}]"
        line += f"  within or said {s['within_or_said']}/{s['rigs']} (said {s['said']})"
        for key, unit in (("rotation_error_deg", "deg"), ("translation_direction_error_deg", "deg"),
                          ("translation_error_rel_baseline", "")):  # fmt: skip
            q = s[key]
            if q["median"] is not None:
                line += f"  {q['median']:.3g}/{q['p90']:.3g}{unit}"
        if "nees_per_dof" in s:
            line += f"  NEES {s['nees_per_dof']:.2f} [{s['nees_band'][0]:.2f}, {s['nees_band'][1]:.2f}]"
            if r := s.get("rotation_errors"):
                line += (
                    f" (rotation {r['nees_per_dof']:.2f}, {r['nees_per_dof_less_mean']:.2f} less its mean error "
                    f"{np.round(r['mean_deg'], 3)} deg)"
                )
        line += f"  false alarms {s['false_alarms']} in {s['steady_frames']} frames"
        if "knocks" in s:
            k = s["knocks"]
            line += f"  knocks {k['detected_within']}/{k['rigs']} within {DETECT_WITHIN} frames"
            if k["determined_before"] is not None:
                line += f" ({k['detected_within_of_determined']} of the {k['determined_before']} determined before it)"
            line += f", {k['within_at_end']} within at the end ({k['within_or_said_at_end']} or said)"
        lines.append(line)
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default="data/eval", help="where the rigs are rendered and the runs kept")
    p.add_argument("--split", choices=SPLITS, default="test")
    p.add_argument("--presets", nargs="+", choices=COUNTS, default=list(COUNTS))
    p.add_argument("--modes", nargs="+", choices=MODES, default=["online"])
    p.add_argument("--only", choices=("steady", "knocked"), help="run only these rigs (two sittings side by side)")
    p.add_argument("--limit", type=int, help="run at most this many new rigs per mode (the rest next time)")
    p.add_argument("--summary-only", action="store_true", help="no new runs: summarise those kept")
    p.add_argument("--out", default=None, help="JSON (default bench/results/calibrate_SPLIT.json)")
    args = p.parse_args()
    root = Path(args.root)
    doc = {"split": args.split, "targets": TARGETS, "frames": FRAMES, "modes": {}}
    for mode in args.modes:
        docs, new = {}, 0
        for name, knocked in rigs(args.split, args.presets):
            if args.only and knocked != (args.only == "knocked"):
                continue
            kept = (root / "runs" / mode / f"{name}{'-knocked' * knocked}.json").exists()
            if not kept and (args.summary_only or (args.limit is not None and new >= args.limit)):
                continue
            new += not kept
            print(f"{mode}: {name}{' (knocked)' * knocked}", flush=True)
            docs[(name, knocked)] = run(root, name, knocked, mode)
        summary = summarise(root, docs)
        print(table(summary, mode))
        rows = [rig_row(root, n, k, d) for (n, k), d in sorted(docs.items())]
        doc["modes"][mode] = {"summary": summary, "rigs": [r["rig"] for r in rows], "rows": rows}
    write_json(args.out or f"bench/results/calibrate_{args.split}.json", doc)


if __name__ == "__main__":
    main()
