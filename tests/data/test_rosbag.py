"""ROS bags written with rosbags from a rendered rig (a ROS 1 bag of raw images, a ROS 2 mcap bag of PNG-compressed
ones, each with CameraInfo and odometry) open to the rig's frames, K and stamps, calibrate as the folder does, and bad
bags are one line and exit 2."""

import json

import cv2
import numpy as np
import pytest
import torch

from ocalib.cli import main
from ocalib.data.layout import open_sequence
from ocalib.data.rosbag import camera_names, extract_bag, image_array, info_topic, pose_matrix
from ocalib.io.poses import read_kitti, read_tum, write_tum
from ocalib.synth import preset

rosbags = pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

torch.set_num_threads(1)
FRAMES = 20
EPOCH_NS = 1_700_000_000 * 10**9  # stamps count from 1970, as drivers' do
PERIOD_NS = 100_000_000  # the render's 10 Hz
ROS1, ROS2 = get_typestore(Stores.ROS1_NOETIC), get_typestore(Stores.ROS2_HUMBLE)
T_BASE_CAM0 = np.array([[0, 0, 1, 0.3], [-1, 0, 0, 0.1], [0, -1, 0, 1.2], [0, 0, 0, 1.0]])  # the ROS 2 bag's tf_static


class Messages:
    """Messages of one typestore ``ts`` (its field names: ROS 1's CameraInfo K, D; ROS 2's k, d)."""

    def __init__(self, ts):
        self.ts, self.ros1 = ts, ts is ROS1

    def __getattr__(self, name):  # Messages(ts).Image -> ts.types["sensor_msgs/msg/Image"]
        return self.ts.types[next(t for t in self.ts.types if t.endswith(f"/msg/{name}"))]

    def header(self, t_ns: int, frame: str):
        time = self.Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        return self.Header(seq=0, stamp=time, frame_id=frame) if self.ros1 else self.Header(stamp=time, frame_id=frame)

    def image(self, t_ns, frame, bgr: np.ndarray, encoding: str):
        array = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB) if encoding == "rgb8" else bgr
        h, w = bgr.shape[:2]
        return self.Image(self.header(t_ns, frame), h, w, encoding, 0, w * 3, array.reshape(-1).copy())

    def compressed(self, t_ns, frame, bgr: np.ndarray):
        data = cv2.imencode(".png", bgr)[1].reshape(-1)
        return self.CompressedImage(self.header(t_ns, frame), "png", data)

    def info(self, t_ns, frame, size, K, model="plumb_bob", D=(0.0,) * 5):
        roi = self.RegionOfInterest(0, 0, 0, 0, False)
        matrices = (np.asarray(D, float), np.asarray(K, float).ravel(), np.eye(3).ravel(), np.zeros(12))
        return self.CameraInfo(self.header(t_ns, frame), size[0], size[1], model, *matrices, 0, 0, roi)

    def odometry(self, t_ns, frame, child, T):
        return self.Odometry(self.header(t_ns, frame), child, self.PoseWithCovariance(self.pose(T), np.zeros(36)), self.TwistWithCovariance(self.Twist(self.Vector3(0.0, 0.0, 0.0), self.Vector3(0.0, 0.0, 0.0)), np.zeros(36)))  # fmt: skip

    def pose(self, T):
        from scipy.spatial.transform import Rotation

        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()  # scipy's order is ROS's
        return self.Pose(self.Point(*T[:3, 3]), self.Quaternion(x, y, z, w))

    def tf_static(self, t_ns, parent, child, T):
        pose = self.pose(T)
        p, q = pose.position, pose.orientation
        transform = self.Transform(self.Vector3(p.x, p.y, p.z), q)
        return self.TFMessage([self.TransformStamped(self.header(t_ns, parent), child, transform)])


def write_bag(path, ts, records, storage=None):
    """``records`` (t_ns, topic, msg) written in time order, one connection a topic: a ROS 1 bag for ROS1's
    typestore, else a ROS 2 one (``storage``: sqlite3 by default)."""
    ros1 = ts is ROS1
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=storage or StoragePlugin.SQLITE3)
    connections = {}
    with writer:
        for t_ns, topic, msg in sorted(records, key=lambda r: r[0]):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            raw = ts.serialize_ros1(msg, msg.__msgtype__) if ros1 else ts.serialize_cdr(msg, msg.__msgtype__)
            writer.write(connections[topic], t_ns, raw)
    return path


def rig_records(rig, ts, compressed: bool, odometry: str = "", skip_odometry: int = 0) -> list:
    """The rendered rig folder ``rig`` as bag records: each camera's images (cam0 as rgb8, cam1 as bgr8, or PNG
    compressed) and CameraInfo; with ``odometry``, camera 0's poses on that topic from its frame ``skip_odometry`` on
    (ROS 1: as camera 0's frame; ROS 2: as base_link's, with /tf_static base_link -> cam0)."""
    m, seq, records = Messages(ts), open_sequence(rig), []
    for cam, encoding in zip(seq.cameras, ("rgb8", "bgr8")):
        topic = f"/{cam.name}/image_raw" + "/compressed" * compressed
        records.append((EPOCH_NS, f"/{cam.name}/camera_info", m.info(EPOCH_NS, cam.name, cam.size, cam.K)))
        for i, path in enumerate(cam.images):
            t_ns, bgr = EPOCH_NS + i * PERIOD_NS, cv2.imread(str(path))
            msg = m.compressed(t_ns, cam.name, bgr) if compressed else m.image(t_ns, cam.name, bgr, encoding)
            records.append((t_ns, topic, msg))
    if odometry:
        body, to_cam0 = ("cam0", np.eye(4)) if m.ros1 else ("base_link", np.linalg.inv(T_BASE_CAM0))
        for i, T in enumerate(seq.cameras[0].poses[skip_odometry:], skip_odometry):
            records.append((EPOCH_NS + i * PERIOD_NS, odometry, m.odometry(EPOCH_NS + i * PERIOD_NS, "odom", body, T @ to_cam0)))  # fmt: skip
        if not m.ros1:
            records.append((EPOCH_NS, "/tf_static", m.tf_static(EPOCH_NS, "base_link", "cam0", T_BASE_CAM0)))
    return records


@pytest.fixture(scope="module")
def rig(render):
    return render(preset("handheld").with_overrides(frames=FRAMES, height=64, width=208, seed=1003))


@pytest.fixture(scope="module")
def bags(rig, tmp_path_factory):
    """The ROS 1 bag (raw images, /odom from frame 0) and the ROS 2 mcap bag (compressed, /odom from frame 3)."""
    root = tmp_path_factory.mktemp("bags")
    ros1 = write_bag(root / "rig.bag", ROS1, rig_records(rig, ROS1, False, "/odom"))
    ros2 = write_bag(root / "rig2", ROS2, rig_records(rig, ROS2, True, "/odom", skip_odometry=3), StoragePlugin.MCAP)
    return ros1, ros2


@pytest.mark.parametrize("which", [0, 1], ids=["ros1-raw", "ros2-mcap-compressed"])
def test_a_bag_opens_to_the_rendered_frames_K_stamps_and_odometry(rig, bags, which, tmp_path):
    bag = bags[which]
    topics = [f"/{c}/image_raw" + "/compressed" * which for c in ("cam0", "cam1")]
    extract = extract_bag(bag, topics, tmp_path / "x", "/odom")
    assert extract.warnings == []  # ROS 1: the odometry's frame is camera 0's; ROS 2: through /tf_static
    seq, truth = open_sequence(extract.folder), open_sequence(rig)
    assert seq.names == truth.names == ["cam0", "cam1"]
    for cam, ref in zip(seq.cameras, truth.cameras):
        assert len(cam) == len(ref) == FRAMES
        np.testing.assert_array_equal(cam.K, ref.K)
        assert cam.distortion is None and cam.size == ref.size
        for a, b in zip(cam.images, ref.images):
            np.testing.assert_array_equal(cv2.imread(str(a)), cv2.imread(str(b)))
        np.testing.assert_allclose(cam.times, EPOCH_NS * 1e-9 + np.arange(FRAMES) / 10, rtol=0, atol=1e-6)
    odometry = read_tum(extract.odometry)
    skipped = 3 * which
    np.testing.assert_allclose(odometry.times, EPOCH_NS * 1e-9 + np.arange(skipped, FRAMES) / 10, rtol=0, atol=1e-6)
    np.testing.assert_allclose(odometry.poses, read_kitti(rig / "cam0" / "poses.txt")[skipped:], atol=1e-6)


def test_a_frame_count_stops_reading_past_camera_0s_last(bags, tmp_path, monkeypatch):
    monkeypatch.setattr("ocalib.data.rosbag.AFTER_LAST_S", 0.25)
    extract = extract_bag(bags[0], ["/cam0/image_raw", "/cam1/image_raw"], tmp_path / "x", "/odom", frames=5)
    seq = open_sequence(extract.folder)
    assert [len(c) for c in seq.cameras] == [5, 7]  # camera 1 to 0.25 s past camera 0's frame 4: its frames 5, 6
    assert len(read_tum(extract.odometry)) == 7


def test_names_sibling_info_topics_and_image_encodings():
    assert camera_names(["/cam0/image_raw", "/cam1/image_raw/compressed"]) == ["cam0", "cam1"]
    assert camera_names(["/a/image", "/a/image2"]) == ["a_image", "a_image2"]  # one namespace: the whole topic
    assert info_topic("/cam1/image_raw/compressed") == info_topic("/cam1/image_raw") == "/cam1/camera_info"
    m = Messages(ROS2)
    grey = (np.arange(12) * 1000).astype(">u2").reshape(3, 4)  # big-endian mono16, each row padded by 2 bytes
    data = np.concatenate([np.r_[row.view(np.uint8), 0, 0] for row in grey]).astype(np.uint8)
    msg = m.Image(m.header(0, "c"), 3, 4, "mono16", 1, 10, data)
    np.testing.assert_array_equal(image_array(msg, "here"), grey.astype(np.uint16))


def small_bag(path, ts=ROS2, info=True, model="plumb_bob", D=(0.0,) * 5, odometry_ns=None, pose_stamped=False):
    """A bag of two 8x8 cameras, 3 frames: /cam0/image_raw and /cam1/image_raw (mono8), their CameraInfo (or none),
    odometry on /odom at ``odometry_ns`` (camera 0's frame, identity poses; or PoseStamped) where given."""
    m, records = Messages(ts), []
    K = [[8.0, 0, 3.5], [0, 8.0, 3.5], [0, 0, 1]]
    for name in ("cam0", "cam1"):
        if info:
            records.append((0, f"/{name}/camera_info", m.info(EPOCH_NS, name, (8, 8), K, model, D)))
        for i in range(3):
            t = EPOCH_NS + i * PERIOD_NS
            grey = np.full(64, 10 * i, np.uint8)
            records.append((t, f"/{name}/image_raw", m.Image(m.header(t, name), 8, 8, "mono8", 0, 8, grey)))
    for t in odometry_ns or ():
        msg = m.PoseStamped(m.header(t, "odom"), m.pose(np.eye(4))) if pose_stamped else m.odometry(t, "odom", "cam0", np.eye(4))  # fmt: skip
        records.append((t, "/odom", msg))
    return write_bag(path, ts, records)


def bad(capsys, bag, *extra, topics=("/cam0/image_raw", "/cam1/image_raw")) -> str:
    """``calibrate --bag`` on ``bag`` -> its one-line error (after checking exit code 2)."""
    assert main(["calibrate", "--bag", str(bag), "--topics", *topics, "--frontend", "opencv", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("ocalib calibrate: error: "), err
    return err.removeprefix("ocalib calibrate: error: ")


def test_bad_bags_are_one_line_naming_the_bag_and_topic(tmp_path, capsys):
    bag = small_bag(tmp_path / "ok")
    assert (
        bad(capsys, tmp_path / "none.bag")
        == f"{tmp_path / 'none.bag'}: no such bag (a ROS 1 .bag file or a ROS 2 bag folder)"
    )
    (tmp_path / "corrupt.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 4)
    assert bad(capsys, tmp_path / "corrupt.bag").startswith(f"{tmp_path / 'corrupt.bag'}: cannot read the bag (")
    err = bad(capsys, bag, topics=("/cam0/image_raw", "/cam2/image_raw"))
    assert err == f"{bag}: no topic /cam2/image_raw (--topics); its image topics: /cam0/image_raw, /cam1/image_raw"
    err = bad(capsys, bag, topics=("/cam0/image_raw", "/cam1/camera_info"))
    assert (
        err
        == f"{bag}: /cam1/camera_info holds sensor_msgs/CameraInfo, not sensor_msgs/Image or sensor_msgs/CompressedImage"
    )
    err = bad(capsys, bag, "--odometry", "/cam0/image_raw")
    assert err.startswith(f"{bag}: /cam0/image_raw holds sensor_msgs/Image, not nav_msgs/Odometry or ")


def test_bad_camera_info_and_odometry_say_how_to_fix_them(tmp_path, capsys):
    bag = small_bag(tmp_path / "unknown", model="kannala_brandt", D=(0.1, 0, 0, 0))
    err = bad(capsys, bag)
    assert (
        err
        == f"{bag}: /cam0/camera_info: unknown distortion model 'kannala_brandt' (models read: plumb_bob, rational_polynomial, equidistant)"
    )
    bag = small_bag(tmp_path / "rational", model="rational_polynomial", D=(0.1, 0, 0, 0, 0, 0.2, 0, 0))
    assert (
        "rational_polynomial with D = [0.1, 0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 0.0]: ocalib's opencv lens has 5 terms"
        in bad(capsys, bag)
    )
    bag = small_bag(tmp_path / "noinfo", info=False)
    err = bad(capsys, bag)
    assert err.startswith(f"{bag}: /cam0/camera_info: no CameraInfo for /cam0/image_raw: give K with --intrinsics FILE")
    late = [EPOCH_NS + 10**9 * k for k in (5, 6)]  # odometry 5 s after the images
    bag = small_bag(tmp_path / "late", odometry_ns=late)
    err = bad(capsys, bag, "--odometry", "/odom")
    assert err.startswith(
        f"{bag}: /odom: odometry from t = 1700000005.000 to 1700000006.000 s, /cam0/image_raw's images"
    )
    assert err.endswith("no image within it")


def test_lenses_and_given_intrinsics(tmp_path):
    seq = open_sequence(extract_bag(small_bag(tmp_path / "fish", model="equidistant", D=(0.1, 0.01, 0, 0)), ["/cam0/image_raw", "/cam1/image_raw"], tmp_path / "a").folder)  # fmt: skip
    assert (seq.cameras[1].distortion.model, seq.cameras[1].distortion.coeffs) == ("fisheye", (0.1, 0.01, 0.0, 0.0))
    (tmp_path / "K.yaml").write_text("fx: 9\nfy: 9\ncx: 3.5\ncy: 3.5\n")
    bag = small_bag(
        tmp_path / "noinfo.bag", ts=ROS1, info=False, odometry_ns=[EPOCH_NS + PERIOD_NS, EPOCH_NS + 2 * PERIOD_NS]
    )
    topics = ["/cam0/image_raw", "/cam1/image_raw"]
    extract = extract_bag(bag, topics, tmp_path / "b", "/odom", intrinsics=tmp_path / "K.yaml")
    assert open_sequence(extract.folder).cameras[0].K[0, 0] == 9
    assert len(read_tum(extract.odometry)) == 2  # frame 0 outside the odometry: left to the metric trajectory's reader


def test_pose_stamped_odometry_is_taken_as_camera_0s_unless_a_pose_is_given(tmp_path):
    bag = small_bag(tmp_path / "ps", odometry_ns=[EPOCH_NS, EPOCH_NS + 2 * PERIOD_NS], pose_stamped=True)
    topics = ["/cam0/image_raw", "/cam1/image_raw"]
    assert extract_bag(bag, topics, tmp_path / "a", "/odom").warnings == [
        f"{bag}: /odom: no transform from its frame (none: a PoseStamped) to camera 0's frame cam0 (/tf_static or "
        "--odometry-to-cam0): its poses are taken as camera 0's"
    ]
    T = pose_matrix((1.0, 2.0, 3.0), (0.0, 0.0, np.sin(0.3), np.cos(0.3)))  # 0.6 rad about z
    np.testing.assert_allclose(T[:2, :2], [[np.cos(0.6), -np.sin(0.6)], [np.sin(0.6), np.cos(0.6)]], atol=1e-12)
    extract = extract_bag(bag, topics, tmp_path / "b", "/odom", odometry_to_cam0=T)
    assert extract.warnings == []
    np.testing.assert_allclose(read_tum(extract.odometry).poses, [T, T], atol=1e-8)


def calibrated(argv, out) -> dict:
    assert main([*argv, "--frontend", "opencv", "--no-bundle-adjust", "--out", str(out)]) == 0
    return json.loads(out.read_text())


def same_extrinsics(a: dict, b: dict) -> None:
    for key in ("quaternion_wxyz", "translation", "scale"):
        np.testing.assert_allclose(a["extrinsics"][0][key], b["extrinsics"][0][key], rtol=0, atol=1e-6, err_msg=key)


def test_calibrating_a_bag_gives_the_folders_extrinsics(rig, bags, tmp_path):
    folder = calibrated(["calibrate", "--sequence", str(rig)], tmp_path / "folder.json")
    topics = ["--topics", "/cam0/image_raw", "/cam1/image_raw"]
    cache = ["--bag-cache", str(tmp_path / "cache")]
    same_extrinsics(folder, calibrated(["calibrate", "--bag", str(bags[0]), *topics, *cache], tmp_path / "bag.json"))
    assert (tmp_path / "cache" / "rig.yaml").is_file()  # kept


def test_a_bags_odometry_is_the_metric_trajectory_and_its_gap_said(rig, bags, tmp_path):
    """The ROS 2 bag's odometry (from frame 3 on, through /tf_static) as the folder's --metric-trajectory."""
    poses = read_kitti(rig / "cam0" / "poses.txt")
    write_tum(tmp_path / "odometry.txt", np.arange(3, FRAMES) / 10, poses[3:])
    metric = ["--metric-trajectory", str(tmp_path / "odometry.txt")]
    folder = calibrated(["calibrate", "--sequence", str(rig), *metric], tmp_path / "folder.json")
    topics = ["--topics", "/cam0/image_raw/compressed", "/cam1/image_raw/compressed", "--odometry", "/odom"]
    bag = calibrated(["calibrate", "--bag", str(bags[1]), *topics], tmp_path / "bag.json")
    same_extrinsics(folder, bag)
    said = [w for w in bag["warnings"] if w.startswith(f"{bags[1]}: /odom: no pose at 3 of the {FRAMES} frames (t = ")]
    assert len(said) == 1, bag["warnings"]
