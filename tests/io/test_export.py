"""``ocalib export``: each format read back by a parser of its own (scipy for the rotations) gives the result JSON's
``T_cam0_camN`` to 1e-9; the intrinsics go where each format wants them; mistakes are one line and exit code 2.

Convention: ``T_cam0_camN`` is the pose of camera N in camera 0's frame, ``p_cam0 = R p_camN + t``."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from ocalib.calib.drivers.options import HeadOptions
from ocalib.calib.poses.pipeline import RigPoses, calibrate_rig
from ocalib.cli import main
from ocalib.data.distortion import Distortion
from ocalib.data.rig import CameraSpec, RigSpec, write_rig_yaml
from ocalib.io.export import ExportCamera, ExportRig, urdf

CAMERAS, FRAMES = 4, 30
LENSES = [
    None,
    Distortion("fisheye", (0.1, 0.01, 1e-3, 1e-4)),
    Distortion("opencv", (-0.2, 0.05, 1e-3, -2e-3, 0.0)),
    None,
]
TOLERANCE = 1e-9


def pose(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """A folder with ``rig.json``, calibrate-poses' result for a rig of random extrinsics (camera 3 at pitch 90 deg,
    URDF's gimbal lock), and ``rig.yaml``, the cameras' intrinsics and lenses, each written by ocalib's own writer."""
    root = tmp_path_factory.mktemp("export")
    rng = np.random.default_rng(7)
    motion = np.stack([pose(R, t) for R, t in zip(
        Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.3, (FRAMES, 3)), 0)).as_matrix(),
        np.cumsum(rng.normal(0, 1, (FRAMES, 3)), 0))])  # fmt: skip
    rotations = [np.eye(3), *Rotation.random(2, random_state=3).as_matrix()]
    rotations.append(Rotation.from_euler("xyz", [0.4, np.pi / 2, -1.1]).as_matrix())
    extrinsics = [pose(R, rng.normal(0, 0.5, 3) if k else 0) for k, R in enumerate(rotations)]
    poses = np.stack([motion @ X for X in extrinsics], 1)
    lines = np.tile(np.arange(1, FRAMES + 1)[:, None], (1, CAMERAS))
    rig = RigPoses([f"cam{k}.txt" for k in range(CAMERAS)], poses, None, lines, [None] * CAMERAS, [None] * CAMERAS)
    (root / "rig.json").write_text(json.dumps(calibrate_rig(rig, HeadOptions(solver="batch")).result_json()))
    K = [np.array([[400.0 + 10 * k, 0, 320 + k], [0, 410.0 + 10 * k, 240 - k], [0, 0, 1]]) for k in range(CAMERAS)]
    specs = [CameraSpec(f"cam{k}", 640 + k, 480 - k, K[k], distortion=LENSES[k]) for k in range(CAMERAS)]
    write_rig_yaml(root / "rig.yaml", RigSpec(specs))
    return root


def truth(files: Path) -> list[np.ndarray]:
    """The JSON's ``T_cam0_camN`` (4, 4), camera 0's the identity."""
    doc = json.loads((files / "rig.json").read_text())
    return [np.eye(4)] + [pose(e["rotation"], e["translation"]) for e in doc["extrinsics"]]


def export(files: Path, fmt: str, *extra: str) -> str:
    out = files / f"out.{fmt}"
    assert main(["export", str(files / "rig.json"), "--format", fmt, "--rig", str(files / "rig.yaml"),
                 "--out", str(out), *extra]) == 0  # fmt: skip
    return out.read_text()


def error_line(capsys, path) -> str:
    """The one line on stderr, an error of ``ocalib export`` naming ``path``."""
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("ocalib export: error: ") and str(path) in lines[0], lines
    return lines[0]


def test_the_json_holds_random_rotations_and_a_gimbal_lock(files):
    T = truth(files)
    assert len(T) == CAMERAS and min(Rotation.from_matrix(X[:3, :3]).magnitude() for X in T[1:]) > 0.3
    assert abs(T[3][2, 0] + 1) < 1e-9  # -sin(pitch) = -1


def test_kalibr_chain_composes_to_the_extrinsics(files):
    chain, T = yaml.safe_load(export(files, "kalibr")), truth(files)
    assert list(chain) == [f"cam{k}" for k in range(CAMERAS)]
    composed = np.eye(4)
    for k in range(1, CAMERAS):
        composed = composed @ np.linalg.inv(np.array(chain[f"cam{k}"]["T_cn_cnm1"]))  # T_cam0_camk-1 T_camk-1_camk
        np.testing.assert_allclose(composed, T[k], atol=TOLERANCE)
    assert "T_cn_cnm1" not in chain["cam0"]


def test_kalibr_intrinsics_and_lenses(files):
    chain = yaml.safe_load(export(files, "kalibr"))
    for k, cam in enumerate(chain.values()):
        assert cam["camera_model"] == "pinhole" and cam["rostopic"] == f"/cam{k}/image_raw"
        assert cam["intrinsics"] == [400.0 + 10 * k, 410.0 + 10 * k, 320 + k, 240 - k]  # integer pixel centres kept
        assert cam["resolution"] == [640 + k, 480 - k]
    assert [c["distortion_model"] for c in chain.values()] == ["radtan", "equidistant", "radtan", "radtan"]
    assert chain["cam0"]["distortion_coeffs"] == [0.0] * 4
    assert chain["cam1"]["distortion_coeffs"] == list(LENSES[1].coeffs)
    assert chain["cam2"]["distortion_coeffs"] == list(LENSES[2].coeffs[:4])


def test_ros_transforms_and_commands_give_the_extrinsics(files):
    doc, T = yaml.safe_load(export(files, "ros")), truth(files)
    assert len(doc["transforms"]) == CAMERAS - 1
    for k, entry in enumerate(doc["transforms"], 1):
        assert (entry["header"]["frame_id"], entry["child_frame_id"]) == ("cam0", f"cam{k}")
        t, q = entry["transform"]["translation"], entry["transform"]["rotation"]
        R = Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]]).as_matrix()  # scipy: scalar last, as ROS
        np.testing.assert_allclose(pose(R, [t["x"], t["y"], t["z"]]), T[k], atol=TOLERANCE)
        words = entry["command"].split()
        assert words[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
        args = dict(zip(words[4::2], words[5::2]))
        assert args.pop("--frame-id") == "cam0" and args.pop("--child-frame-id") == f"cam{k}"
        assert {key: float(v) for key, v in args.items()} == {f"--{a}": t[a] for a in "xyz"} | {
            f"--q{a}": q[a] for a in "xyzw"
        }


def test_urdf_joints_give_the_extrinsics(files):
    robot, T = ET.fromstring(export(files, "urdf")), truth(files)
    assert [link.get("name") for link in robot.iter("link")] == [f"cam{k}" for k in range(CAMERAS)]
    joints = robot.findall("joint")
    assert len(joints) == CAMERAS - 1
    for k, joint in enumerate(joints, 1):
        assert joint.get("type") == "fixed" and joint.get("name") == f"cam0_to_cam{k}"
        assert (joint.find("parent").get("link"), joint.find("child").get("link")) == ("cam0", f"cam{k}")
        origin = joint.find("origin")
        xyz, rpy = (np.array(origin.get(key).split(), float) for key in ("xyz", "rpy"))
        R = Rotation.from_euler("xyz", rpy).as_matrix()  # fixed axes x, y, z: Rz(yaw) Ry(pitch) Rx(roll)
        np.testing.assert_allclose(pose(R, xyz), T[k], atol=TOLERANCE)
        assert abs(rpy[1]) <= np.pi / 2


@pytest.mark.parametrize("yaw", [-2.0, np.pi])  # cos(pitch) rounds below 0 at both: pitch stays within pi/2
@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2])
def test_urdf_at_gimbal_lock_is_exact(pitch, yaw):
    R = Rotation.from_euler("xyz", [0.7, pitch, yaw]).as_matrix()
    rig = ExportRig([ExportCamera("a", np.eye(4)), ExportCamera("b", pose(R, [1, 2, 3]))])
    origin = ET.fromstring(urdf(rig)).find("joint/origin")
    rpy = np.array(origin.get("rpy").split(), float)
    np.testing.assert_allclose(Rotation.from_euler("xyz", rpy).as_matrix(), R, atol=1e-12)
    assert rpy[2] == 0 and rpy[1] == pytest.approx(pitch) and abs(rpy[1]) <= np.pi / 2


def test_colmap_rig_config_gives_the_extrinsics(files):
    [rig], T = json.loads(export(files, "colmap")), truth(files)
    cameras = rig["cameras"]
    assert [c["image_prefix"] for c in cameras] == [f"cam{k}/" for k in range(CAMERAS)]
    assert cameras[0]["ref_sensor"] is True and "cam_from_rig_rotation" not in cameras[0]
    for k, cam in enumerate(cameras[1:], 1):
        w, x, y, z = cam["cam_from_rig_rotation"]  # COLMAP's order
        cam_from_rig = pose(Rotation.from_quat([x, y, z, w]).as_matrix(), cam["cam_from_rig_translation"])
        np.testing.assert_allclose(np.linalg.inv(cam_from_rig), T[k], atol=TOLERANCE)
    models = ["PINHOLE", "OPENCV_FISHEYE", "OPENCV", "PINHOLE"]
    assert [c["camera_model_name"] for c in cameras] == models
    for k, cam in enumerate(cameras):
        assert cam["camera_params"][:4] == [400.0 + 10 * k, 410.0 + 10 * k, 320.5 + k, 240.5 - k]  # centres + 0.5
    assert cameras[2]["camera_params"][4:] == list(LENSES[2].coeffs[:4])


def test_colmap_reads_the_rig_config(files):
    pycolmap = pytest.importorskip("pycolmap")
    export(files, "colmap")
    [config], T = pycolmap.read_rig_config(files / "out.colmap"), truth(files)
    assert [c.ref_sensor for c in config.cameras] == [True] + [False] * (CAMERAS - 1)
    for k, cam in enumerate(config.cameras[1:], 1):
        np.testing.assert_allclose(
            np.linalg.inv(np.vstack([cam.cam_from_rig.matrix(), [0, 0, 0, 1]])), T[k], atol=TOLERANCE
        )
    assert config.cameras[1].camera.model.name == "OPENCV_FISHEYE"


def test_frame_prefix_names_the_frames(files):
    robot = ET.fromstring(export(files, "urdf", "--frame-prefix", "rig/cam"))
    assert robot.find("joint/parent").get("link") == "rig/cam0" and robot.find("joint/child").get("link") == "rig/cam1"


def test_without_intrinsics_colmap_has_the_rig_and_kalibr_is_refused(files, tmp_path, capsys):
    out = tmp_path / "rig_config.json"
    assert main(["export", str(files / "rig.json"), "--format", "colmap", "--out", str(out)]) == 0
    assert all("camera_model_name" not in c for c in json.loads(out.read_text())[0]["cameras"])
    capsys.readouterr()
    assert main(["export", str(files / "rig.json"), "--format", "kalibr"]) == 2
    assert "--rig" in error_line(capsys, files / "rig.json")


def test_the_calibrated_sequences_rig_yaml_is_read(files, tmp_path, capsys):
    doc = json.loads((files / "rig.json").read_text())
    doc["settings"]["sequence"], doc["units"] = str(files), "metres"  # as ocalib calibrate writes it
    (tmp_path / "rig.json").write_text(json.dumps(doc))
    assert main(["export", str(tmp_path / "rig.json"), "--format", "kalibr"]) == 0
    captured = capsys.readouterr()
    assert yaml.safe_load(captured.out)["cam3"]["resolution"] == [643, 477]
    assert captured.err == "" and "# translations in metres" in captured.out


def test_units_not_metres_are_said(files, capsys):
    assert main(["export", str(files / "rig.json"), "--format", "ros"]) == 0
    captured = capsys.readouterr()
    assert "not known to be metres" in captured.err and "not known to be metres" in captured.out


@pytest.mark.parametrize(
    "name, content",
    [
        ("missing.json", None),
        ("binary.json", bytes(range(256))),
        ("text.json", b"reference: cam0\n"),
        ("list.json", b"[1, 2, 3]"),
        ("rig_yaml_as.json", json.dumps({"cameras": [{"name": "cam0"}]}).encode()),
        ("no_rotation.json", json.dumps({"reference": "a", "extrinsics": [{"camera": "b", "translation": [0, 0, 0]}]}).encode()),
        ("null.json", json.dumps({"reference": "a", "extrinsics": [{"camera": "b", "rotation": None, "translation": [0, 0, 0]}]}).encode()),
        ("skew.json", json.dumps({"reference": "a", "extrinsics": [{"camera": "b", "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 2]], "translation": [0, 0, 0]}]}).encode()),
    ],
)  # fmt: skip
def test_a_bad_result_json_is_one_line_and_exit_2(tmp_path, capsys, name, content):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    assert main(["export", str(path), "--format", "urdf"]) == 2
    error_line(capsys, path)


def test_a_rig_yaml_without_a_camera_of_the_result_is_one_line_and_exit_2(files, tmp_path, capsys):
    other = tmp_path / "rig.yaml"
    write_rig_yaml(other, RigSpec([CameraSpec("front", 640, 480, np.eye(3))]))
    assert main(["export", str(files / "rig.json"), "--format", "kalibr", "--rig", str(other)]) == 2
    assert "cam0.txt" in error_line(capsys, other)


def test_kalibr_refuses_a_lens_with_k3(files, tmp_path, capsys):
    lens = Distortion("opencv", (0.1, 0.0, 0.0, 0.0, 0.01))
    rig = tmp_path / "rig.yaml"
    write_rig_yaml(rig, RigSpec([CameraSpec(f"cam{k}", 640, 480, np.eye(3), distortion=lens) for k in range(CAMERAS)]))
    assert main(["export", str(files / "rig.json"), "--format", "kalibr", "--rig", str(rig)]) == 2
    assert "k3" in capsys.readouterr().err


def test_a_rendered_rigs_kalibr_chain_is_its_truth(render, tmp_path):
    """A rendered rig calibrated from its cameras' ground-truth pose files (``calibrate-poses``, batch) and exported
    with its own rig.yaml: Kalibr's ``T_cn_cnm1`` is the renderer's ``T_cam1_cam0`` and its intrinsics the render's
    K (camera names matched to the rig folder's ``CAMERA/poses.txt``)."""
    from ocalib.data.layout import open_sequence
    from ocalib.synth import preset

    path = render(preset("handheld").with_overrides(frames=40, height=32, width=96, seed=1011))
    cams = open_sequence(path).cameras
    result, camchain = tmp_path / "rig.json", tmp_path / "camchain.yaml"
    poses = [str(path / cam.name / "poses.txt") for cam in cams]
    assert main(["calibrate-poses", *poses, "--solver", "batch", "--out", str(result)]) == 0
    assert main(["export", str(result), "--format", "kalibr", "--rig", str(path / "rig.yaml"),
                 "--out", str(camchain)]) == 0  # fmt: skip
    chain = yaml.safe_load(camchain.read_text())
    truth = np.linalg.inv(np.linalg.inv(cams[0].T_cam0_cam) @ cams[1].T_cam0_cam)
    T = np.array(chain[cams[1].name]["T_cn_cnm1"])
    assert Rotation.from_matrix(T[:3, :3] @ truth[:3, :3].T).magnitude() < 1e-6
    np.testing.assert_allclose(T[:3, 3], truth[:3, 3], atol=1e-6)
    for cam in cams:
        K = cam.K
        assert chain[cam.name]["intrinsics"] == pytest.approx([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
        assert chain[cam.name]["resolution"] == [int(cam.size[1]), int(cam.size[0])]
