"""Pose files.

Convention: every pose is camera-to-world, a 4x4 float64 matrix; quaternions in code are (w, x, y, z).

* KITTI: one pose a line, 12 numbers, the row-major top 3x4 of the matrix. No timestamps (KITTI keeps
  them in a separate ``times.txt``, one number a line).
* TUM: ``timestamp tx ty tz qx qy qz qw`` a line (qw LAST in the file), timestamps strictly increasing.
* EuRoC / ASL CSV (EuRoC ground truth, VINS, OKVIS, Kalibr): ``timestamp [ns], px, py, pz, qw, qx, qy, qz``
  (qw FIRST, nanoseconds), then any further columns (velocity, biases), which are ignored.

All: ``#`` comments and blank lines are skipped, numbers are separated by whitespace or commas. Every
format error is an :class:`~ocalib.errors.InputError` naming ``file:line``. NaN/inf values and
non-orthonormal rotations are *not* read errors (the calibration skips and counts them): check them with
:func:`pose_validity` and report them with :func:`describe_invalid`.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ocalib.errors import InputError, read_text

POSE_TOLERANCE = 1e-3  # rotation orthonormality error above which a pose is invalid (as the head's default)

KITTI_COLUMNS = 12
TUM_COLUMNS = 8
EUROC_COLUMNS = 8  # at least: timestamp, position, quaternion (w first)
NANOSECONDS = 1e12  # a first timestamp above this is in nanoseconds (in seconds it would be the year 33,658)
FORMATS = ("auto", "kitti", "tum", "euroc")
# how to name an EuRoC file where it cannot be told (calibrate's --metric-trajectory has no --format)
EUROC_HINT = "start the file with EuRoC's header (#timestamp [ns],p_RS_R_x [m],...,q_RS_w [],...), or give calibrate-poses --format euroc"


@dataclass
class Trajectory:
    """One camera's poses as read from a file.

    poses: (N, 4, 4) float64, camera-to-world. times: (N,) float64 seconds, strictly increasing, or None
    (KITTI without times.txt). path: the file. lines: (N,) int, the 1-based file line of each pose.
    """

    poses: np.ndarray
    times: np.ndarray | None
    path: Path
    lines: np.ndarray

    def __len__(self) -> int:
        return len(self.poses)


def _read_rows(path: str | Path, columns: int | None = None, what: str = "pose file") -> tuple[np.ndarray, np.ndarray]:
    """Numbers of a pose file -> rows (N, C) float64 and their 1-based lines (N,).

    ``columns=None`` takes the count of the first data line, which must be 12 (KITTI) or 8 (TUM). ``what``: what
    the messages call the file.
    """
    path = Path(path)
    text = read_text(path, what)
    fast = _read_rows_fast(text, columns)
    if fast is not None:
        return fast
    rows, lines = [], []
    for lineno, line in enumerate(text.splitlines(), 1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        try:
            values = [float(v) for v in text.replace(",", " ").split()]
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in {text[:60]!r}") from None
        if columns is None:
            if len(values) not in (KITTI_COLUMNS, TUM_COLUMNS):
                raise InputError(
                    f"{path}:{lineno}: cannot tell the pose format: {len(values)} numbers on the line, expected "
                    f"{KITTI_COLUMNS} (KITTI: row-major 3x4 pose) or {TUM_COLUMNS} (TUM: t tx ty tz qx qy qz qw); "
                    f"for EuRoC / ASL CSV (t[ns] px py pz qw qx qy qz ...) {EUROC_HINT}"
                )
            columns = len(values)
        elif len(values) != columns:
            kind = {KITTI_COLUMNS: "KITTI: a row-major 3x4 pose", TUM_COLUMNS: "TUM: t tx ty tz qx qy qz qw"}.get(
                columns, "as on the first pose line"
            )
            raise InputError(f"{path}:{lineno}: expected {columns} numbers ({kind}), got {len(values)}")
        rows.append(values)
        lines.append(lineno)
    if not rows:
        content = "poses" if what == "pose file" else "numbers"
        raise InputError(f"{path}: no {content} in the file (empty, or only comments)")
    return np.asarray(rows, dtype=np.float64), np.asarray(lines)


def _read_rows_fast(text: str, columns: int | None) -> tuple[np.ndarray, np.ndarray] | None:
    """numpy's parser on the data lines (20x faster than Python's); None where anything is off, so that the
    line-by-line reader above finds and names the problem."""
    kept = [(i, t) for i, line in enumerate(text.splitlines(), 1) if (t := line.strip()) and not t.startswith("#")]
    if not kept:
        return None
    try:
        rows = np.loadtxt(io.StringIO("\n".join(t for _, t in kept).replace(",", " ")), dtype=np.float64, ndmin=2)
    except ValueError:
        return None
    if (
        len(rows) != len(kept)
        or rows.shape[1] != (columns or rows.shape[1])
        or rows.shape[1] not in (columns, KITTI_COLUMNS, TUM_COLUMNS)
    ):
        return None
    return rows, np.array([i for i, _ in kept])


def _check_times(times: np.ndarray, path: Path, lines: np.ndarray) -> None:
    """Raise InputError at the first non-finite, duplicate or decreasing timestamp."""
    bad = ~np.isfinite(times)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"{path}:{lines[i]}: timestamp is {times[i]}")
    step = np.diff(times)
    if (step <= 0).any():
        i = int(np.argmax(step <= 0)) + 1
        what = "duplicate timestamp" if step[i - 1] == 0 else "timestamp goes back in time"
        raise InputError(
            f"{path}:{lines[i]}: {what}: {float(times[i])!r} after {float(times[i - 1])!r} at line {lines[i - 1]} "
            "(timestamps must be strictly increasing)"
        )


def read_kitti(path: str | Path) -> np.ndarray:
    """Read a KITTI pose file -> (N, 4, 4) float64. Errors name the file and line."""
    return _kitti_poses(_read_rows(path, KITTI_COLUMNS)[0])


def _kitti_poses(rows: np.ndarray) -> np.ndarray:
    poses = np.zeros((len(rows), 4, 4))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    poses[:, 3, 3] = 1
    return poses


def write_kitti(path: str | Path, poses) -> None:
    """Write poses (N, 4, 4) (numpy or torch) as a KITTI pose file."""
    poses = _numpy(poses)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, poses[:, :3, :].reshape(-1, 12), fmt="%.9e")


def read_times(path: str | Path) -> np.ndarray:
    """Read a ``times.txt`` (one timestamp a line) -> (N,) float64 seconds, strictly increasing.

    Stamps are seconds, or nanoseconds (what ROS and most drivers write) where the first is over
    :data:`NANOSECONDS`; every stamp of a file is in the same unit. Every problem is an InputError naming the file
    and line (an empty file, a folder, a non-number, NaN or inf, a stamp not after the one before).
    """
    path = Path(path)
    rows, lines = _read_rows(path, 1, "times file")
    times = rows[:, 0]
    nanoseconds = times[0] > NANOSECONDS
    if np.isfinite(times).all() and ((times > NANOSECONDS) != nanoseconds).any():
        i = int(np.argmax((times > NANOSECONDS) != nanoseconds))
        units = ("nanoseconds", "seconds") if nanoseconds else ("seconds", "nanoseconds")
        raise InputError(
            f"{path}:{lines[i]}: stamp {float(times[i])!r} is in {units[1]}, the first ({float(times[0])!r}, line "
            f"{lines[0]}) in {units[0]}: one unit a file (a stamp over {NANOSECONDS:.0e} is nanoseconds)"
        )
    _check_times(times, path, lines)
    return times * 1e-9 if nanoseconds else times


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory file -> Trajectory with times (N,).

    Convention: the file stores ``qx qy qz qw``; quaternions are normalised on read, and a quaternion of
    (near-)zero norm is an InputError. Timestamps must be finite and strictly increasing.
    """
    path = Path(path)
    return _tum_trajectory(*_read_rows(path, TUM_COLUMNS), path)


def _tum_trajectory(rows: np.ndarray, lines: np.ndarray, path: Path) -> Trajectory:
    import torch  # here, as in write_tum and pose_validity: opening a sequence's layout loads no torch

    from ocalib.geometry.quaternion import quaternion_to_rotation_matrix

    times = rows[:, 0].copy()
    _check_times(times, path, lines)
    q = rows[:, [7, 4, 5, 6]]  # (w, x, y, z)
    norm = np.linalg.norm(q, axis=1)
    tiny = norm < 1e-6  # NaN norms fall through: a NaN pose, flagged by pose_validity
    if tiny.any():
        i = int(np.argmax(tiny))
        raise InputError(f"{path}:{lines[i]}: quaternion (qx qy qz qw) = {rows[i, 4:].tolist()} has norm {norm[i]:.3g}")
    poses = np.zeros((len(rows), 4, 4))
    poses[:, :3, :3] = quaternion_to_rotation_matrix(torch.from_numpy(q)).numpy()
    poses[:, :3, 3] = rows[:, 1:4]
    poses[:, 3, 3] = 1
    return Trajectory(poses, times, path, lines)


def write_tum(path: str | Path, times, poses) -> None:
    """Write times (N,) and poses (N, 4, 4) (numpy or torch) as a TUM file ``t tx ty tz qx qy qz qw``."""
    import torch

    from ocalib.geometry.quaternion import rotation_matrix_to_quaternion

    times, poses = _numpy(times), _numpy(poses)
    if times.shape != poses.shape[:1]:
        raise InputError(f"{path}: {len(times)} timestamps for {len(poses)} poses")
    q = rotation_matrix_to_quaternion(torch.from_numpy(poses[:, :3, :3].copy())).numpy()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for t, xyz, (w, x, y, z) in zip(times, poses[:, :3, 3], q):
            f.write(f"{t:.9f} " + " ".join(f"{v:.9e}" for v in (*xyz, x, y, z, w)) + "\n")


def read_euroc(path: str | Path) -> Trajectory:
    """Read an EuRoC / ASL CSV trajectory -> Trajectory with times (N,) in seconds.

    Convention: the file stores ``timestamp [ns], px, py, pz, qw, qx, qy, qz, ...``; further columns are ignored,
    quaternions are normalised on read (a near-zero one is an InputError), timestamps must strictly increase.
    """
    path = Path(path)
    rows, lines = _read_rows(path, _first_line_columns(path))
    if rows.shape[1] < EUROC_COLUMNS:
        raise InputError(f"{path}:{lines[0]}: {rows.shape[1]} numbers on the line; EuRoC / ASL CSV needs at least "
                         f"{EUROC_COLUMNS} (timestamp [ns], px, py, pz, qw, qx, qy, qz)")  # fmt: skip
    tum = np.concatenate([rows[:, :1] * 1e-9, rows[:, 1:4], rows[:, 5:8], rows[:, 4:5]], 1)  # TUM's column order
    return _tum_trajectory(tum, lines, path)


def read_poses(path: str | Path, format: str = "auto", times: str | Path | None = None) -> Trajectory:
    """Read a KITTI, TUM or EuRoC / ASL CSV pose file -> Trajectory.

    format: "auto", "kitti", "tum" or "euroc". Auto: a header naming the quaternion w-first (EuRoC's ``q_RS_w``,
    or ``qw`` before ``qx``) -> EuRoC; else from the first pose line: 12 numbers -> KITTI, 8 -> TUM. An 8-number
    file whose first timestamp is in nanoseconds without such a header is refused: TUM and headerless EuRoC
    differ only in the quaternion's order, which the numbers cannot tell.
    times: a KITTI ``times.txt`` with one timestamp per pose (KITTI only; TUM and EuRoC files carry their own).
    """
    path = Path(path)
    if format not in FORMATS:
        raise InputError(f"{path}: unknown pose format {format!r} ({', '.join(FORMATS)})")
    read_text(path, "pose file")  # a missing, folder or binary file named as such before the format is sniffed
    if format == "auto" and _w_first_header(path):
        format = "euroc"
    if format == "euroc":
        if times is not None:
            raise InputError(f"{path}: an EuRoC file carries its own timestamps; drop the times file {times}")
        return read_euroc(path)
    rows, lines = _read_rows(path, {"auto": None, "kitti": KITTI_COLUMNS, "tum": TUM_COLUMNS}[format])
    if format == "auto" and rows.shape[1] == TUM_COLUMNS and rows[0, 0] > NANOSECONDS:
        raise InputError(
            f"{path}:{lines[0]}: 8 numbers a line with a timestamp in nanoseconds ({rows[0, 0]:.6g}): TUM "
            f"(t tx ty tz qx qy qz qw, seconds) or EuRoC / ASL (t[ns] px py pz qw qx qy qz)? For EuRoC {EUROC_HINT}; "
            "for TUM, calibrate-poses takes --format tum"
        )
    if rows.shape[1] == TUM_COLUMNS:
        if times is not None:
            raise InputError(f"{path}: a TUM file carries its own timestamps; drop the times file {times}")
        return _tum_trajectory(rows, lines, path)
    stamps = None
    if times is not None:
        stamps = read_times(times)
        if len(stamps) != len(rows):
            raise InputError(f"{times}: {len(stamps)} timestamps for the {len(rows)} poses of {path}")
    return Trajectory(_kitti_poses(rows), stamps, path, lines)


def _w_first_header(path: Path) -> bool:
    """Whether the file's comment header names a w-first quaternion (EuRoC's ``q_RS_w`` ... ``q_RS_x``, ``qw`` ...
    ``qx``)."""
    with open(path, errors="replace") as f:
        for line in f:
            text = line.strip().lower()
            if text and not text.startswith("#"):
                return False
            names = [m.group(1) for m in re.finditer(r"\bq\w*?_?([wxyz])\b", text)]
            if "w" in names and "x" in names:
                return names.index("w") < names.index("x")
    return False


def _first_line_columns(path: Path) -> int | None:
    """The count of numbers on the first pose line (None for a file without one: the reader then says so)."""
    with open(path, errors="replace") as f:
        for line in f:
            text = line.strip()
            if text and not text.startswith("#"):
                return len(text.replace(",", " ").split())
    return None


def pose_validity(poses, tol: float = POSE_TOLERANCE) -> np.ndarray:
    """Which poses (N, 4, 4) are usable -> bool (N,): all finite, rotation orthonormal with det +1 within tol."""
    import torch

    from ocalib.geometry.pose import orthonormality_error

    poses = _numpy(poses)
    finite = np.isfinite(poses).all(axis=(1, 2))
    R = np.where(finite[:, None, None], poses[:, :3, :3], np.eye(3))  # keep NaN out of det
    return finite & (orthonormality_error(torch.from_numpy(R)).numpy() <= tol)


def describe_invalid(path: str | Path, mask, lines=None, shown: int = 10) -> str | None:
    """Readable summary of the invalid poses (``mask`` False), or None when all are valid.

    lines: (N,) file line of each pose (``Trajectory.lines``); default pose index + 1. For example
    ``"cam1.txt: 3 of 500 poses invalid at lines 17, 18, 40 (NaN/inf or non-orthonormal rotation)"``.
    """
    mask = np.asarray(mask, dtype=bool)
    lines = np.arange(1, len(mask) + 1) if lines is None else np.asarray(lines)
    bad = lines[~mask]
    if not len(bad):
        return None
    listed = ", ".join(str(v) for v in bad[:shown]) + (f" and {len(bad) - shown} more" if len(bad) > shown else "")
    where = "line" if len(bad) == 1 else "lines"
    return f"{path}: {len(bad)} of {len(mask)} poses invalid at {where} {listed} (NaN/inf or non-orthonormal rotation)"


def _numpy(x) -> np.ndarray:
    """numpy or torch -> float64 numpy."""
    return np.asarray(x.detach().cpu() if hasattr(x, "detach") else x, dtype=np.float64)
