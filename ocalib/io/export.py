"""A calibration in other tools' formats: Kalibr's camchain, ROS 2 static transforms, URDF, COLMAP's rig config.

:func:`read_result` reads the result JSON of ``ocalib calibrate`` / ``calibrate-poses`` into an :class:`ExportRig`,
:func:`with_intrinsics` adds the cameras' K, size and lens from a rig.yaml, and each format is one pure function
``(rig, prefix) -> text``, listed in :data:`FORMATS`. Frames are named ``{prefix}0`` (the reference),
``{prefix}1``, ... in the order of the JSON (Kalibr's keys are always ``cam0``, ``cam1``, ...).

Convention: ``T_cam0_camN`` (4, 4) is the pose of camera N in camera 0's frame, ``p_cam0 = R p_camN + t``; camera 0
is the reference; quaternions (w, x, y, z) inside, each format's own order in its file; translations in the
result's units (metres where the calibration had a metric trajectory). ocalib's K has integer pixel centres, as
OpenCV's and Kalibr's; COLMAP's are at +0.5.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from ocalib.errors import InputError, read_text
from ocalib.geometry.se3 import invert

METRES = "metres"
ORTHONORMAL_TOLERANCE = 1e-6  # a result's rotation further than this from a rotation matrix: not a result JSON


@dataclass(frozen=True)
class ExportCamera:
    """One camera: its name in the result JSON (a pose file, a sequence's camera), ``T_cam0_cam`` (4, 4) float64 and,
    where known, K (3, 3) in pixels, ``size`` (width, height) and ``distortion`` (``model``, ``coeffs`` as
    :class:`ocalib.data.distortion.Distortion`; None: a pinhole)."""

    name: str
    T_cam0_cam: np.ndarray
    K: np.ndarray | None = None
    size: tuple[int, int] | None = None
    distortion: object | None = None


@dataclass(frozen=True)
class ExportRig:
    """The cameras (camera 0 first), the translations' units, the calibrated sequence's folder where the JSON names
    one, and the notes a user of the export must read (units not metric, extrinsics not determined)."""

    cameras: list[ExportCamera]
    units: str = METRES
    sequence: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def has_intrinsics(self) -> bool:
        return all(cam.K is not None for cam in self.cameras)


def read_result(path: str | Path) -> ExportRig:
    """The extrinsics of the result JSON at ``path``; an :class:`InputError` naming it for a missing, binary or
    malformed file, or a JSON of another kind."""
    path = Path(path)
    try:
        doc = json.loads(read_text(path, "result JSON"))
    except json.JSONDecodeError as err:
        raise InputError(f"{path}: not valid JSON ({err})") from None
    if not (
        isinstance(doc, dict) and isinstance(doc.get("reference"), str) and isinstance(doc.get("extrinsics"), list)
    ):
        raise InputError(f"{path}: not a result JSON of ocalib calibrate / calibrate-poses (no reference, extrinsics)")
    cameras = [ExportCamera(doc["reference"], np.eye(4))]
    cameras += [_camera(entry, f"{path}: extrinsics[{i}]") for i, entry in enumerate(doc["extrinsics"])]
    units = str(doc.get("units", "camera 0's trajectory units"))
    notes = [] if units == METRES else [f"translations in {units}, not known to be metres"]
    notes += [
        f"{e['camera']}: its extrinsic is not determined" for e in doc["extrinsics"] if e.get("determined") is False
    ]
    settings = doc.get("settings")
    sequence = settings.get("sequence") if isinstance(settings, dict) else None
    return ExportRig(cameras, units, sequence if isinstance(sequence, str) else None, notes)


def _camera(entry, where: str) -> ExportCamera:
    """An object of the JSON's ``extrinsics`` -> its camera; an :class:`InputError` naming ``where`` otherwise."""
    try:
        name, R, t = str(entry["camera"]), np.asarray(entry["rotation"], float), np.asarray(entry["translation"], float)
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{where}: needs camera, rotation (3x3) and translation (3 numbers)") from None
    if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise InputError(f"{where} ({name}): rotation must be 3x3 and translation 3 numbers, all finite")
    if np.abs(R.T @ R - np.eye(3)).max() > ORTHONORMAL_TOLERANCE or np.linalg.det(R) < 0:
        raise InputError(f"{where} ({name}): rotation is not a rotation matrix")
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return ExportCamera(name, T)


def with_intrinsics(rig: ExportRig, specs: list, where: str | Path) -> ExportRig:
    """``rig`` with each camera's K, size and lens from the rig.yaml cameras ``specs`` (objects with ``name``,
    ``width``, ``height``, ``K``, ``distortion``, as :class:`ocalib.data.rig.CameraSpec`), matched by name, by the
    stem of a pose file's name, or by the folder of a rig folder's ``CAMERA/poses.txt``; an :class:`InputError`
    naming ``where`` for a camera it does not have."""
    by_name = {spec.name: spec for spec in specs}
    cameras = []
    for cam in rig.cameras:
        path = Path(cam.name)
        spec = by_name.get(cam.name) or by_name.get(path.stem) or by_name.get(path.parent.name)
        if spec is None:
            raise InputError(f"{where}: no camera {cam.name!r} of the result (cameras: {', '.join(by_name)})")
        K, size = np.asarray(spec.K, dtype=np.float64), (int(spec.width), int(spec.height))
        cameras.append(replace(cam, K=K, size=size, distortion=spec.distortion))
    return replace(rig, cameras=cameras)


def _quaternion(R: np.ndarray) -> list[float]:
    """Rotation matrix (3, 3) -> quaternion (w, x, y, z), w >= 0, by
    :func:`ocalib.geometry.rotation_matrix_to_quaternion`."""
    import torch

    from ocalib.geometry import rotation_matrix_to_quaternion

    return rotation_matrix_to_quaternion(torch.from_numpy(np.ascontiguousarray(R))).tolist()


def _comments(rig: ExportRig, prefix: str) -> list[str]:
    """What a file's comments say: which camera each frame is, the units, the notes."""
    names = [f"{prefix}{n}: {cam.name}" + (" (the reference)" if n == 0 else "") for n, cam in enumerate(rig.cameras)]
    metric = [f"translations in {METRES}"] if rig.units == METRES else []  # else the notes say what they are in
    return ["ocalib calibration", *names, *metric, *rig.notes]


def _numbers(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def kalibr_camchain(rig: ExportRig, prefix: str = "cam") -> str:
    """Kalibr's ``camchain.yaml``: per camera ``camN`` the pinhole ``intrinsics`` [fu, fv, pu, pv] (ocalib's K
    unchanged: Kalibr's pixel centres are integers too), the lens (``radtan`` [k1, k2, p1, p2] for ``opencv`` and for
    a pinhole (zeros), ``equidistant`` [k1, k2, k3, k4] for ``fisheye``), ``resolution`` [w, h] and ``rostopic``
    ``/{prefix}N/image_raw``; from camera 1 on, ``T_cn_cnm1`` (4x4 rows). Needs the intrinsics.

    Convention: ``T_cn_cnm1`` takes points of camera N-1 into camera N, ``p_camN = T_cn_cnm1 p_camN-1``:
    ``inverse(T_cam0_camN) T_cam0_camN-1``.
    """
    chain = {}
    for n, cam in enumerate(rig.cameras):
        model, coeffs = _kalibr_lens(cam)
        chain[f"cam{n}"] = {
            "camera_model": "pinhole",
            "intrinsics": [float(v) for v in (cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2])],
            "distortion_model": model,
            "distortion_coeffs": coeffs,
            "resolution": list(cam.size),
            "rostopic": f"/{prefix}{n}/image_raw",
        } | ({"T_cn_cnm1": (invert(cam.T_cam0_cam) @ rig.cameras[n - 1].T_cam0_cam).tolist()} if n else {})
    comments = "".join(f"# {line}\n" for line in _comments(rig, "cam"))
    return comments + yaml.safe_dump(chain, sort_keys=False, default_flow_style=None)


def _kalibr_lens(cam: ExportCamera) -> tuple[str, list[float]]:
    """Kalibr's distortion model and coefficients of a camera's lens; an :class:`InputError` for an OpenCV lens with
    a k3, which Kalibr's radtan does not have."""
    if cam.distortion is None:
        return "radtan", [0.0] * 4
    coeffs = [float(c) for c in cam.distortion.coeffs]
    if cam.distortion.model == "fisheye":
        return "equidistant", coeffs
    if coeffs[4] != 0:
        raise InputError(
            f"{cam.name}: its lens has k3 = {coeffs[4]:g}, which Kalibr's radtan (k1 k2 p1 p2) cannot hold"
        )
    return "radtan", coeffs[:4]


def ros_static_transforms(rig: ExportRig, prefix: str = "cam") -> str:
    """ROS 2 static transforms (YAML): ``units`` and per camera N >= 1 a ``geometry_msgs/TransformStamped``'s fields
    (``header.frame_id`` ``{prefix}0``, ``child_frame_id`` ``{prefix}N``, ``transform.translation`` {x, y, z},
    ``transform.rotation`` {x, y, z, w}) with the ``ros2 run tf2_ros static_transform_publisher`` command that
    publishes it.

    Convention: a transform is the child's pose in the parent's frame, ``T_cam0_camN``; ROS's quaternions are
    (x, y, z, w).
    """
    transforms = []
    for n, cam in enumerate(rig.cameras[1:], 1):
        (x, y, z), (qw, qx, qy, qz) = cam.T_cam0_cam[:3, 3].tolist(), _quaternion(cam.T_cam0_cam[:3, :3])
        parent, child = f"{prefix}0", f"{prefix}{n}"
        command = " ".join(f"--{k} {v!r}" for k, v in dict(x=x, y=y, z=z, qx=qx, qy=qy, qz=qz, qw=qw).items())
        transforms.append({
            "header": {"frame_id": parent},
            "child_frame_id": child,
            "transform": {"translation": {"x": x, "y": y, "z": z}, "rotation": {"x": qx, "y": qy, "z": qz, "w": qw}},
            "command": f"ros2 run tf2_ros static_transform_publisher {command} --frame-id {parent} --child-frame-id {child}",
        })  # fmt: skip
    comments = "".join(f"# {line}\n" for line in _comments(rig, prefix))
    return comments + yaml.safe_dump({"units": rig.units, "transforms": transforms}, sort_keys=False, width=1000)


def urdf(rig: ExportRig, prefix: str = "cam") -> str:
    """A URDF robot ``rig``: a link per camera, ``{prefix}0`` the root, and per camera N >= 1 a fixed joint
    ``{prefix}0_to_{prefix}N`` whose origin is ``xyz`` and ``rpy`` (radians, fixed axes:
    ``R = Rz(yaw) Ry(pitch) Rx(roll)``, :func:`ocalib.geometry.angles.rpy_radians`, exact at gimbal lock too).

    Convention: a joint's origin is the child link's pose in the parent's frame, ``T_cam0_camN``.
    """
    from ocalib.geometry.angles import rpy_radians

    robot = ET.Element("robot", name="rig")
    for line in _comments(rig, prefix):
        robot.append(ET.Comment(f" {line.replace('--', '- -')} "))
    for n in range(len(rig.cameras)):
        ET.SubElement(robot, "link", name=f"{prefix}{n}")
    for n, cam in enumerate(rig.cameras[1:], 1):
        joint = ET.SubElement(robot, "joint", name=f"{prefix}0_to_{prefix}{n}", type="fixed")
        ET.SubElement(joint, "parent", link=f"{prefix}0")
        ET.SubElement(joint, "child", link=f"{prefix}{n}")
        xyz, rpy = _numbers(cam.T_cam0_cam[:3, 3]), _numbers(rpy_radians(cam.T_cam0_cam[:3, :3]))
        ET.SubElement(joint, "origin", xyz=xyz, rpy=rpy)
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def colmap_intrinsics(K: np.ndarray, distortion) -> tuple[str, list[float]]:
    """COLMAP's camera model and parameters of ocalib's K (3, 3) and lens (:mod:`ocalib.data.distortion`; None:
    PINHOLE ``fx, fy, cx, cy``): ``opencv`` as OPENCV (``..., k1, k2, p1, p2``), or FULL_OPENCV
    (``..., k3, k4, k5, k6`` with k4 = k5 = k6 = 0) where k3 is not 0; ``fisheye`` as OPENCV_FISHEYE
    (``..., k1, k2, k3, k4``). The principal point moves by +0.5 to COLMAP's pixel centres, here and only here."""
    params = [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]) + 0.5, float(K[1, 2]) + 0.5]
    if distortion is None:
        return "PINHOLE", params
    coeffs = [float(c) for c in distortion.coeffs]
    if distortion.model == "fisheye":
        return "OPENCV_FISHEYE", params + coeffs
    if coeffs[4] == 0:
        return "OPENCV", params + coeffs[:4]
    return "FULL_OPENCV", params + coeffs + [0.0, 0.0, 0.0]


def colmap_rig_config(rig: ExportRig, prefix: str = "cam") -> str:
    """COLMAP's rig configuration (JSON; ``colmap rig_configurator --rig_config_path``, ``pycolmap.read_rig_config``):
    one rig whose images of camera N are under ``{prefix}N/``, camera 0 its reference sensor, the others with
    ``cam_from_rig_rotation`` (w, x, y, z) and ``cam_from_rig_translation``; with the intrinsics, every camera's
    ``camera_model_name`` and ``camera_params`` (:func:`colmap_intrinsics`).

    Convention: COLMAP's ``cam_from_rig`` takes rig (camera 0) points into camera N: ``inverse(T_cam0_camN)``.
    """
    cameras = []
    for n, cam in enumerate(rig.cameras):
        entry = {"image_prefix": f"{prefix}{n}/"}
        if n == 0:
            entry["ref_sensor"] = True
        else:
            T = invert(cam.T_cam0_cam)
            entry |= {"cam_from_rig_rotation": _quaternion(T[:3, :3]), "cam_from_rig_translation": T[:3, 3].tolist()}
        if cam.K is not None:
            model, params = colmap_intrinsics(cam.K, cam.distortion)
            entry |= {"camera_model_name": model, "camera_params": params}
        cameras.append(entry)
    return json.dumps([{"cameras": cameras}], indent=2) + "\n"


@dataclass(frozen=True)
class Format:
    """An export format: its writer ``(rig, prefix) -> text``, whether it needs the intrinsics, and a line of help."""

    write: Callable[[ExportRig, str], str]
    needs_intrinsics: bool
    help: str


FORMATS = {
    "kalibr": Format(kalibr_camchain, True, "Kalibr's camchain.yaml (needs the intrinsics)"),
    "ros": Format(ros_static_transforms, False, "ROS 2 static transforms (YAML, with tf2_ros command lines)"),
    "urdf": Format(urdf, False, "a URDF robot: a link per camera, a fixed joint from camera 0 to each"),
    "colmap": Format(colmap_rig_config, False, "COLMAP's rig config JSON (camera models where intrinsics are known)"),
}
