"""ROS bags (ROS 1 ``.bag``; ROS 2 folders of ``.db3`` or ``.mcap``) extracted to ocalib's rig layout, for
``ocalib calibrate --bag``.

The bag is read once, in its order (rosbags' ``AnyReader``), and each image is written as a PNG when it comes, so
that one image at a time is in memory. The folder written is the native rig layout (:mod:`ocalib.data.rig_layout`),
then opened like any other sequence, every check with it (``calibrate --bag`` writes it to a temporary folder,
removed when it ends, or to ``--bag-cache DIR``, kept):

```
OUT/rig.yaml                  # a camera per image topic, in the order given: K and lens from its CameraInfo
OUT/<name>/images/000000.png  # the topic's images in the bag's order (sensor_msgs/Image or CompressedImage)
OUT/<name>/times.txt          # their header stamps, seconds: the cameras are paired in time by them
OUT/odometry.txt              # with an odometry topic: camera 0's poses at the odometry's stamps (TUM)
```

A camera is named after its topic's namespace (``/cam0/image_raw`` and ``/cam0/image_raw/compressed``: ``cam0``),
and its CameraInfo is the first message of the sibling topic ``<namespace>/camera_info``; the images are taken as the
raw images it describes (its K and D, not its rectified P). The odometry (``nav_msgs/Odometry`` or
``geometry_msgs/PoseStamped``) is the pose of its body frame; camera 0's pose is that times the body-to-camera-0
transform: the one given, else the chain of ``/tf_static`` from the odometry's ``child_frame_id`` to camera 0's
``frame_id``, else the identity, said in a warning (the trajectory taken as camera 0's).

Convention: ROS quaternions are (x, y, z, w), ocalib's (w, x, y, z); poses camera-to-world 4x4 float64 in metres;
stamps in seconds; K (3, 3) in pixels with integer pixel centres, as ROS's CameraInfo and ocalib's (no shift).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from ocalib.data.distortion import Distortion, read_distortion
from ocalib.data.intrinsics import read_intrinsics
from ocalib.data.rig import CameraSpec, RigSpec, write_rig_yaml
from ocalib.errors import InputError
from ocalib.geometry import quaternion_to_rotation_matrix
from ocalib.io.poses import write_tum

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
ODOMETRY_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped")
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
TF_STATIC = "/tf_static"
AFTER_LAST_S = 2.0  # with a frame count: seconds of the bag read past camera 0's last frame (the others', odometry)
# ROS's distortion_model -> ocalib's lens model (ocalib.data.distortion) and its number of coefficients
LENS_MODELS = {"plumb_bob": ("opencv", 5), "rational_polynomial": ("opencv", 5), "equidistant": ("fisheye", 4)}
# sensor_msgs/Image encodings read: pixel type, channels, the cv2 conversion to what cv2.imwrite takes (BGR or grey)
ENCODINGS = {
    "mono8": (np.uint8, 1, None),
    "8UC1": (np.uint8, 1, None),
    "mono16": (np.uint16, 1, None),
    "16UC1": (np.uint16, 1, None),
    "bgr8": (np.uint8, 3, None),
    "rgb8": (np.uint8, 3, cv2.COLOR_RGB2BGR),
    "bgra8": (np.uint8, 4, cv2.COLOR_BGRA2BGR),
    "rgba8": (np.uint8, 4, cv2.COLOR_RGBA2BGR),
    "bgr16": (np.uint16, 3, None),
    "rgb16": (np.uint16, 3, cv2.COLOR_RGB2BGR),
}


@dataclass
class BagCamera:
    """One image topic as it is extracted: its images' stamps (s), size (H, W), frame_id and first CameraInfo."""

    topic: str
    name: str
    info_topic: str
    times: list[float] = field(default_factory=list)
    size: tuple[int, int] | None = None
    frame_id: str = ""
    info: object | None = None


@dataclass
class BagExtract:
    """What :func:`extract_bag` wrote: the rig folder, camera 0's metric trajectory file (or None), lines to print
    (``notes``) and warnings for the result."""

    folder: Path
    odometry: Path | None
    notes: list[str]
    warnings: list[str]


def camera_names(topics: list[str]) -> list[str]:
    """A camera name per image topic: its namespace (``/cam0/image_raw[/compressed]`` -> ``cam0``, ``/a/b/image`` ->
    ``a_b``), or the whole topic where namespaces are missing or repeat."""
    names = []
    for topic in topics:
        parts = [p for p in topic.split("/") if p]
        if parts and parts[-1] == "compressed":
            parts = parts[:-1]
        names.append("_".join(parts[:-1]))
    if len(set(names)) < len(names) or not all(names):
        names = ["_".join(p for p in t.split("/") if p) for t in topics]
    return names


def info_topic(topic: str) -> str:
    """The CameraInfo topic beside image topic ``topic`` (``/cam0/image_raw[/compressed]`` -> ``/cam0/camera_info``)."""
    base = topic.removesuffix("/compressed").rstrip("/")
    return base.rsplit("/", 1)[0] + "/camera_info"


def open_bag(bag: str | Path):
    """An opened rosbags ``AnyReader`` of ``bag`` (a ``.bag`` file, a ROS 2 folder, or the ``.db3``/``.mcap`` file of
    one); a missing or unreadable bag is an :class:`InputError` naming it. Close it after use."""
    from rosbags.highlevel import AnyReader

    path = Path(bag)
    if not path.exists():
        raise InputError(f"{bag}: no such bag (a ROS 1 .bag file or a ROS 2 bag folder)")
    if path.is_file() and path.suffix in (".db3", ".mcap"):
        path = path.parent
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as err:  # rosbags' errors (and the storage's own) say what is wrong with the file
        raise InputError(f"{bag}: cannot read the bag ({type(err).__name__}: {err})") from None
    return reader


def select_connections(reader, bag, topics: list[str], odometry: str | None) -> dict[str, list]:
    """The connections of the topics read, by topic: the image ``topics``, their CameraInfo, ``odometry`` and
    /tf_static; a topic missing or of another message type is an :class:`InputError`."""
    by_topic: dict[str, list] = {}
    for c in reader.connections:
        by_topic.setdefault(c.topic, []).append(c)
    images = sorted(t for t, cs in by_topic.items() if cs[0].msgtype in IMAGE_TYPES)
    wanted = [(t, IMAGE_TYPES, "--topics") for t in topics] + (
        [(odometry, ODOMETRY_TYPES, "--odometry")] * bool(odometry)
    )
    for topic, types, option in wanted:
        if topic not in by_topic:
            listed = ", ".join(images) if images else "none"
            raise InputError(f"{bag}: no topic {topic} ({option}); its image topics: {listed}")
        if by_topic[topic][0].msgtype not in types:
            kinds = " or ".join(t.replace("/msg/", "/") for t in types)
            raise InputError(f"{bag}: {topic} holds {by_topic[topic][0].msgtype.replace('/msg/', '/')}, not {kinds}")
    read = {t: None for t in [*topics, *([odometry] if odometry else [])]}
    read |= {info_topic(t): INFO_TYPE for t in topics} | {TF_STATIC: "tf2_msgs/msg/TFMessage"}
    return {t: by_topic[t] for t, kind in read.items() if t in by_topic and kind in (None, by_topic[t][0].msgtype)}


def stamp(msg) -> float:
    """A message's header stamp, seconds."""
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def image_array(msg, where: str) -> np.ndarray:
    """A ``sensor_msgs/Image`` or ``CompressedImage`` -> (H, W, 3) BGR or (H, W) grey, uint8 or uint16, as
    ``cv2.imwrite`` takes it; an encoding not read or an undecodable image is an :class:`InputError` naming ``where``."""
    if hasattr(msg, "format"):  # CompressedImage
        array = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
        if array is None:
            raise InputError(f"{where}: cannot decode the compressed image (format {msg.format!r})")
        return array[:, :, :3] if array.ndim == 3 and array.shape[2] == 4 else array
    if msg.encoding not in ENCODINGS:
        raise InputError(f"{where}: image encoding {msg.encoding!r} is not read (encodings: {', '.join(ENCODINGS)})")
    dtype, channels, conversion = ENCODINGS[msg.encoding]
    pixel = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row = msg.width * channels * pixel.itemsize
    if msg.step < row or len(msg.data) != msg.height * msg.step:
        raise InputError(f"{where}: {len(msg.data)} bytes for a {msg.height}x{msg.width} {msg.encoding} image")
    rows = np.asarray(msg.data, dtype=np.uint8).reshape(msg.height, msg.step)[:, :row]
    array = np.ascontiguousarray(rows).view(pixel).astype(dtype).reshape(msg.height, msg.width, channels)
    array = array[:, :, 0] if channels == 1 else array
    return cv2.cvtColor(array, conversion) if conversion is not None else array


def lens(model: str, D, where: str) -> Distortion | None:
    """CameraInfo's ``distortion_model`` and D -> ocalib's :class:`Distortion` (None: no distortion, all of D 0);
    an unknown model, or terms ocalib's models lack, are an :class:`InputError` naming ``where``."""
    D = [float(d) for d in D]
    if not any(D) and model in (*LENS_MODELS, ""):
        return None
    if model not in LENS_MODELS:
        raise InputError(f"{where}: unknown distortion model {model!r} (models read: {', '.join(LENS_MODELS)})")
    ocalib_model, count = LENS_MODELS[model]
    coeffs = D[:count] + [0.0] * (count - len(D))
    if any(D[count:]):
        raise InputError(
            f"{where}: {model} with D = {D}: ocalib's {ocalib_model} lens has {count} terms, the rest must be 0"
        )
    return read_distortion({"model": ocalib_model, "coeffs": coeffs}, where)


def camera_spec(cam: BagCamera, bag, intrinsics: str | Path | None) -> CameraSpec:
    """The rig.yaml entry of ``cam``: K and lens from its CameraInfo, else K from the ``intrinsics`` file (a
    pinhole); neither is an :class:`InputError` saying how to give K."""
    where = f"{bag}: {cam.info_topic}"
    height, width = cam.size
    info = cam.info
    K = None if info is None else np.asarray(getattr(info, "k", getattr(info, "K", None)), dtype=np.float64)
    if K is None or K.size != 9 or K[0] <= 0 or K[4] <= 0:
        if intrinsics is not None:
            return CameraSpec(cam.name, width, height, read_intrinsics(intrinsics, (height, width)))
        got = "no CameraInfo" if info is None else "a CameraInfo without K (all 0)"
        raise InputError(
            f"{where}: {got} for {cam.topic}: give K with --intrinsics FILE (K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] "
            "or fx, fy, cx, cy in YAML; used for every camera without a CameraInfo)"
        )
    if (info.height, info.width) not in ((0, 0), (height, width)):
        raise InputError(
            f"{where}: CameraInfo of {info.height}x{info.width} images, {cam.topic}'s are {height}x{width}"
        )
    distortion = lens(info.distortion_model, getattr(info, "d", getattr(info, "D", ())), where)
    return CameraSpec(cam.name, width, height, K.reshape(3, 3), distortion=distortion)


def pose_matrix(xyz, xyzw) -> np.ndarray:
    """A translation (x, y, z) and a ROS quaternion (x, y, z, w) -> the 4x4 pose; a zero quaternion is an
    :class:`InputError`."""
    q = torch.tensor([[xyzw[3], xyzw[0], xyzw[1], xyzw[2]]], dtype=torch.float64)
    if not q.norm() > 1e-6:
        raise InputError(f"quaternion (x, y, z, w) = {list(xyzw)} is not a rotation")
    T = np.eye(4)
    T[:3, :3] = quaternion_to_rotation_matrix(q / q.norm()).numpy()[0]
    T[:3, 3] = xyz
    return T


def ros_pose(position, orientation) -> np.ndarray:
    """A ROS ``Point``/``Vector3`` and ``Quaternion`` -> the 4x4 pose."""
    return pose_matrix(
        (position.x, position.y, position.z), (orientation.x, orientation.y, orientation.z, orientation.w)
    )


def odometry_pose(msg) -> np.ndarray:
    """An Odometry's or PoseStamped's pose of its body in its world, 4x4."""
    pose = msg.pose.pose if hasattr(msg, "child_frame_id") else msg.pose
    return ros_pose(pose.position, pose.orientation)


def static_transform(transforms: dict[str, tuple[str, np.ndarray]], parent: str, child: str) -> np.ndarray | None:
    """``T_parent_child`` (4x4) through the tree of /tf_static (``transforms``: child -> (parent, T_parent_child)),
    None where either frame is not in it or they have no common root."""

    def to_root(frame: str) -> tuple[str, np.ndarray]:
        T, seen = np.eye(4), set()
        while frame in transforms and frame not in seen:
            seen.add(frame)
            frame, T_up = transforms[frame][0], transforms[frame][1]
            T = T_up @ T
        return frame, T

    (root_p, T_root_parent), (root_c, T_root_child) = to_root(parent), to_root(child)
    if root_p != root_c or not ({parent, child} & set(transforms)):
        return None
    return np.linalg.inv(T_root_parent) @ T_root_child


@dataclass
class BagOdometry:
    """The odometry topic as read: its body frame (``child_frame_id``; none for a PoseStamped), stamps (s), poses."""

    topic: str
    frame: str = ""
    times: list[float] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)


def _bag_errors() -> tuple[type[Exception], ...]:
    """The exceptions rosbags raises for a bag it cannot read."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    from rosbags.serde import SerdeError

    return AnyReaderError, Reader1Error, Reader2Error, SerdeError


def extract_bag(
    bag: str | Path,
    topics: list[str],
    out: str | Path,
    odometry: str | None = None,
    odometry_to_cam0: np.ndarray | None = None,
    intrinsics: str | Path | None = None,
    frames: int | None = None,
) -> BagExtract:
    """Extract the image ``topics`` of ``bag`` (the first is camera 0) and its ``odometry`` topic into the rig folder
    ``out`` (missing or empty), read once, in order. ``odometry_to_cam0``: camera 0's pose in the odometry's body frame
    (4, 4), where /tf_static lacks it; ``intrinsics``: a K file for cameras without a CameraInfo; ``frames``: camera
    0's first frames only (the bag read to :data:`AFTER_LAST_S` past the last). Every problem with the bag is an
    :class:`InputError` naming it and the topic."""
    out = Path(out)
    if len(set(topics)) < len(topics):
        raise InputError(f"{bag}: --topics names a topic twice: {' '.join(topics)}")
    if out.exists() and any(out.iterdir()):
        raise InputError(f"{out}: the folder to extract {bag} into is not empty")
    cams = [BagCamera(t, n, info_topic(t)) for t, n in zip(topics, camera_names(topics))]
    odo = BagOdometry(odometry) if odometry else None
    reader = open_bag(bag)
    try:
        connections = select_connections(reader, bag, topics, odometry)
        transforms = _stream(reader, bag, [c for cs in connections.values() for c in cs], cams, odo, out, frames)
    except _bag_errors() as err:
        raise InputError(f"{bag}: cannot read the bag ({type(err).__name__}: {err})") from None
    finally:
        reader.close()
    for cam in cams:
        if not cam.times:
            raise InputError(f"{bag}: {cam.topic} holds no messages")
    specs = [camera_spec(c, bag, intrinsics) for c in cams]
    write_rig_yaml(out / "rig.yaml", RigSpec(specs, _frame_rate(cams[0].times)))
    for cam in cams:
        np.savetxt(out / cam.name / "times.txt", cam.times, fmt="%.9f")
    counts = ", ".join(f"{c.name} {len(c.times)}" for c in cams)
    notes = [f"{bag}: images extracted to {out} ({counts})"]
    if odo is None:
        return BagExtract(out, None, notes, [])
    T_body_cam0, said, warnings = _odometry_to_cam0(bag, odo, cams[0], transforms, odometry_to_cam0)
    times, poses = _camera0_trajectory(bag, odo, cams[0], T_body_cam0)
    write_tum(out / "odometry.txt", times, poses)
    return BagExtract(out, out / "odometry.txt", notes + said, warnings)


def _stream(reader, bag, connections: list, cams: list[BagCamera], odo: BagOdometry | None, out: Path, frames=None):
    """Read the ``connections``' messages once, in the bag's order (to :data:`AFTER_LAST_S` past camera 0's frame
    ``frames`` where given): images written as they come, the first CameraInfo and every odometry pose kept -> the
    /tf_static transforms (child -> (parent, T_parent_child))."""
    images = {c.topic: c for c in cams}
    infos = {c.info_topic: c for c in cams}
    transforms: dict[str, tuple[str, np.ndarray]] = {}
    end = None  # the bag time (ns) to read to, once camera 0 has its frames
    for connection, t_ns, raw in reader.messages(connections=connections):
        if end is not None and t_ns > end:
            break
        msg, topic = reader.deserialize(raw, connection.msgtype), connection.topic
        if topic in images and (topic != cams[0].topic or end is None):
            _write_image(images[topic], msg, bag, out)
            if frames is not None and len(cams[0].times) == frames and end is None:
                end = t_ns + int(AFTER_LAST_S * 1e9)
        elif topic in infos and infos[topic].info is None:
            infos[topic].info = msg
        elif odo is not None and topic == odo.topic:
            odo.frame = getattr(msg, "child_frame_id", "")
            odo.times.append(stamp(msg))
            odo.poses.append(odometry_pose(msg))
        elif topic == TF_STATIC:
            for tf in msg.transforms:
                transforms[tf.child_frame_id] = (
                    tf.header.frame_id,
                    ros_pose(tf.transform.translation, tf.transform.rotation),
                )
    return transforms


def _write_image(cam: BagCamera, msg, bag, out: Path) -> None:
    """Write image message ``msg`` of ``cam`` as its next PNG and keep its stamp; a stamp not after the one before or
    a change of size is an :class:`InputError`."""
    where, t = f"{bag}: {cam.topic} message {len(cam.times)}", stamp(msg)
    if cam.times and t <= cam.times[-1]:
        raise InputError(f"{where}: header stamp {t:.9f} s is not after the one before ({cam.times[-1]:.9f} s)")
    array = image_array(msg, where)
    if cam.size is None:
        cam.size, cam.frame_id = array.shape[:2], msg.header.frame_id
        (out / cam.name / "images").mkdir(parents=True, exist_ok=True)
    elif array.shape[:2] != cam.size:
        raise InputError(
            f"{where}: a {array.shape[0]}x{array.shape[1]} image, the first was {cam.size[0]}x{cam.size[1]}"
        )
    cv2.imwrite(str(out / cam.name / "images" / f"{len(cam.times):06d}.png"), array, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    cam.times.append(t)


def _frame_rate(times: list[float]) -> float:
    """Frames a second of stamps ``times`` (s), their median period's; 10 for a single frame."""
    return 1.0 / float(np.median(np.diff(times))) if len(times) > 1 else 10.0


def _odometry_to_cam0(bag, odo: BagOdometry, cam0: BagCamera, transforms: dict, given: np.ndarray | None):
    """Camera 0's pose in the odometry's body frame (4, 4): ``given``, the identity where the body is camera 0's
    frame, /tf_static's chain, else the identity -> (T_body_cam0, lines to print, warnings)."""
    where = f"{bag}: {odo.topic}"
    if given is not None:
        return given, [f"{where}: camera 0 at the pose given in the odometry's frame"], []
    if odo.frame and odo.frame == cam0.frame_id:
        return np.eye(4), [], []
    T = static_transform(transforms, odo.frame, cam0.frame_id) if odo.frame and cam0.frame_id else None
    if T is not None:
        return T, [f"{where}: camera 0's pose is {odo.frame}'s times {odo.frame} -> {cam0.frame_id} of {TF_STATIC}"], []
    body, frame = odo.frame or "(none: a PoseStamped)", cam0.frame_id or "(none)"
    return (
        np.eye(4),
        [],
        [
            f"{where}: no transform from its frame {body} to camera 0's frame {frame} ({TF_STATIC} or "
            "--odometry-to-cam0): its poses are taken as camera 0's"
        ],
    )


def _camera0_trajectory(bag, odo: BagOdometry, cam0: BagCamera, T_body_cam0: np.ndarray):
    """Camera 0's poses (M, 4, 4) at the odometry's stamps (M,), sorted, each once; odometry with no stamp within
    camera 0's images' span is an :class:`InputError` (some outside: those frames are left out later, and said)."""
    where = f"{bag}: {odo.topic}"
    if not odo.times:
        raise InputError(f"{where} holds no messages")
    times, first = np.unique(np.asarray(odo.times), return_index=True)
    images = np.asarray(cam0.times)
    if not ((images >= times[0]) & (images <= times[-1])).any():
        raise InputError(
            f"{where}: odometry from t = {times[0]:.3f} to {times[-1]:.3f} s, {cam0.topic}'s images from "
            f"{images[0]:.3f} to {images[-1]:.3f} s: no image within it"
        )
    return times, np.stack(odo.poses)[first] @ T_body_cam0
