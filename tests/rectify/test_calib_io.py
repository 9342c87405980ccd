import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from lenspair.rectify.calib_io import load_calibration
from lenspair.rectify.calib_ros import message_as_camera_info
from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rectification import StereoRectification
from lenspair.rectify.rig import DistortionModel, StereoRig, write_kalibr
from tests.rectify.rigs import make_rig


def assert_same_rig(found: StereoRig, expected: StereoRig, atol: float = 1e-9) -> None:
    for a, b in ((found.cam0, expected.cam0), (found.cam1, expected.cam1)):
        assert a.distortion_model == b.distortion_model and a.resolution == b.resolution
        np.testing.assert_allclose(a.intrinsics, b.intrinsics, atol=atol)
        np.testing.assert_allclose(a.distortion, b.distortion, atol=atol)
    np.testing.assert_allclose(found.T_cam1_cam0, expected.T_cam1_cam0, atol=atol)


def write_storage(path: Path, values: dict[str, Any]) -> Path:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in values.items():
        storage.write(key, value)
    storage.release()
    return path


def opencv_stereo_keys(rig: StereoRig, naming: str = "K") -> dict[str, Any]:
    m = "K" if naming == "K" else "M"
    return {
        f"{m}1": rig.cam0.K,
        "D1": rig.cam0.dist_coeffs,
        f"{m}2": rig.cam1.K,
        "D2": rig.cam1.dist_coeffs,
        "R": rig.R,
        "T": rig.t.reshape(3, 1),
    }


def test_kalibr_camchain(tmp_path: Path) -> None:
    rig = make_rig("equidistant", rotated=True)
    write_kalibr(tmp_path / "camchain.yaml", rig)
    found, source = load_calibration([tmp_path / "camchain.yaml"])
    assert_same_rig(found, rig)
    assert source.startswith("Kalibr camchain") and "camchain.yaml" in source


@pytest.mark.parametrize("suffix", [".yaml", ".xml"])
def test_opencv_stereo_file(tmp_path: Path, suffix: str) -> None:
    rig = make_rig()
    keys = {**opencv_stereo_keys(rig), "image_size": np.array([720, 540])}
    path = write_storage(tmp_path / f"stereo{suffix}", keys)
    found, source = load_calibration([path])
    assert_same_rig(found, rig)
    assert source.startswith("OpenCV FileStorage")


def test_opencv_sample_intrinsics_and_extrinsics_files(tmp_path: Path) -> None:
    rig = make_rig()
    keys = opencv_stereo_keys(rig, naming="M")
    intrinsics = write_storage(
        tmp_path / "intrinsics.yml", {k: keys[k] for k in ("M1", "D1", "M2", "D2")}
    )
    extrinsics = write_storage(
        tmp_path / "extrinsics.yml", {"R": keys["R"], "T": keys["T"], "Q": np.eye(4)}
    )
    with pytest.raises(RectifyError, match=r"intrinsics\.yml: no image size"):
        load_calibration([intrinsics, extrinsics])
    found, _ = load_calibration([intrinsics, extrinsics], resolutions=[(720, 540)] * 2)
    assert_same_rig(found, rig)
    # each camera its own size: cam1's was taken to be cam0's, and its frames refused
    found, _ = load_calibration([intrinsics, extrinsics], resolutions=[(720, 540), (1440, 1080)])
    assert found.cam0.resolution == (720, 540) and found.cam1.resolution == (1440, 1080)


@pytest.mark.parametrize("stated", [True, False])
def test_opencv_single_camera_files_fisheye(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, stated: bool
) -> None:
    rig = make_rig("equidistant", rotated=True)
    paths = []
    for name, camera in (("left", rig.cam0), ("right", rig.cam1)):
        values = {
            "image_width": 720,
            "image_height": 540,
            "fisheye_model": 1,
            "camera_matrix": camera.K,
            "distortion_coefficients": camera.dist_coeffs,
        }
        if not stated:
            del values["fisheye_model"]
        paths.append(write_storage(tmp_path / f"{name}.yml", values))
    rotation_vector = cv2.Rodrigues(rig.R)[0]
    paths.append(write_storage(tmp_path / "stereo.yml", {"R": rotation_vector, "T": rig.t}))
    found, _ = load_calibration(paths)
    if stated:
        assert_same_rig(found, rig, atol=1e-9)
        assert not caplog.records
    else:  # cv2.fisheye's 4 coefficients, no model named: read as radtan, which is said
        assert found.cam0.distortion_model == "radtan"
        said = [r.getMessage() for r in caplog.records if "no distortion_model" in r.getMessage()]
        assert [line.split(":")[0] for line in said] == [str(paths[0]), str(paths[1])]
        assert all("distortion_model: equidistant" in line for line in said)


def test_opencv_k3_is_refused_not_dropped(tmp_path: Path) -> None:
    rig = make_rig()
    keys = {**opencv_stereo_keys(rig), "image_size": np.array([720, 540])}
    keys["D2"] = np.array([[-0.28, 0.07, 0.0, 0.0, 0.013]])
    path = write_storage(tmp_path / "stereo.yml", keys)
    with pytest.raises(RectifyError, match=r"stereo\.yml: cam1: distortion has k3 .*recalibrate"):
        load_calibration([path])


@pytest.mark.parametrize("scale", [1000.0, 100.0])
def test_opencv_baseline_in_millimetres_or_centimetres_is_refused(
    tmp_path: Path, scale: float
) -> None:
    rig = make_rig()
    keys = {**opencv_stereo_keys(rig), "image_size": np.array([720, 540])}
    keys["T"] = keys["T"] * scale  # 0.11 m written as 110 (mm) or 11 (cm): it said "mm?" to 11
    with pytest.raises(RectifyError, match=r"in metres \(millimetres or centimetres\?\)"):
        load_calibration([write_storage(tmp_path / "stereo.yml", keys)])


@pytest.mark.parametrize(("scale", "message"), [(0.0, "sit at one point"), (np.nan, "NaN")])
def test_a_baseline_of_zero_or_nan_is_one_error_naming_the_file(
    tmp_path: Path, scale: float, message: str
) -> None:
    rig = make_rig()
    keys = {**opencv_stereo_keys(rig), "image_size": np.array([720, 540])}
    keys["T"] = keys["T"] * scale  # cv2.stereoRectify asserted on it
    with pytest.raises(RectifyError, match=rf"stereo\.yml.*{message}"):
        load_calibration([write_storage(tmp_path / "stereo.yml", keys)])


def ros_files(folder: Path, rig: StereoRig) -> tuple[Path, Path]:
    """camera_info YAML pair as ROS camera_calibration writes it for a rectified pair."""
    rectification = StereoRectification.from_rig(rig)
    paths = []
    for name, camera in (("left", rig.cam0), ("right", rig.cam1)):
        view = "cam0" if name == "left" else "cam1"
        model = "plumb_bob" if camera.distortion_model == "radtan" else "equidistant"
        coefficients = list(camera.distortion) + ([0.0] if model == "plumb_bob" else [])

        def matrix(values: np.ndarray) -> dict[str, Any]:
            return {
                "rows": values.shape[0],
                "cols": values.shape[1],
                "data": values.ravel().tolist(),
            }

        data = {
            "image_width": 720,
            "image_height": 540,
            "camera_name": name,
            "camera_matrix": matrix(camera.K),
            "distortion_model": model,
            "distortion_coefficients": {"rows": 1, "cols": len(coefficients), "data": coefficients},
            "rectification_matrix": matrix(rectification.rotation(view)),
            "projection_matrix": matrix(rectification.projection(view)),
        }
        paths.append(folder / f"{name}.yaml")
        paths[-1].write_text(yaml.safe_dump(data, sort_keys=False))
    return paths[0], paths[1]


@pytest.mark.parametrize(("model", "rotated"), [("radtan", False), ("equidistant", True)])
def test_ros_camera_info_pair(tmp_path: Path, model: DistortionModel, rotated: bool) -> None:
    rig = make_rig(model, rotated)
    left, right = ros_files(tmp_path, rig)
    found, source = load_calibration([left, right])
    assert_same_rig(found, rig, atol=1e-9)
    assert "extrinsic from the projection matrices" in source


@pytest.mark.parametrize("ros", [1, 2])
def test_echoed_camera_info_messages_load_as_the_camera_calibration_pair(
    tmp_path: Path, ros: int
) -> None:
    # `rostopic echo -n 1 .../camera_info > left.yaml` (ROS 1: K, D, R, P) or
    # `ros2 topic echo --once` (k, d, r, p): the message's fields, then '---'
    rig = make_rig("equidistant", rotated=True)
    echoed = []
    for path in ros_files(tmp_path, rig):
        data = yaml.safe_load(path.read_text())
        fields = {"k": "camera_matrix", "d": "distortion_coefficients"}
        fields |= {"r": "rectification_matrix", "p": "projection_matrix"}
        message: dict[str, Any] = {
            "header": {"frame_id": f"{path.stem}_optical"},
            "height": data["image_height"],
            "width": data["image_width"],
            "distortion_model": data["distortion_model"],
        }
        for key, name in fields.items():
            message[key.upper() if ros == 1 else key] = data[name]["data"]
        echoed.append(tmp_path / f"echo_{path.name}")
        echoed[-1].write_text(yaml.safe_dump(message, sort_keys=False) + "---\n")
    found, source = load_calibration(echoed)
    assert_same_rig(found, rig, atol=1e-9)
    assert "extrinsic from the projection matrices" in source
    with pytest.raises(RectifyError, match="camera_name"):  # frame ids name the sides
        load_calibration(echoed[::-1])


@pytest.mark.parametrize("model", ["radtan", "equidistant"])
def test_an_empty_camera_info_distortion_is_no_distortion(
    tmp_path: Path, model: DistortionModel
) -> None:
    # drivers of rectified or simulated streams publish D: [], which ROS's image_geometry
    # reads as no distortion; it was "distortion_coefficients is empty or contains NaN"
    rig = make_rig(model)
    for path in ros_files(tmp_path, rig):
        data = yaml.safe_load(path.read_text())
        data["distortion_coefficients"] = {"rows": 1, "cols": 0, "data": []}
        path.write_text(yaml.safe_dump(data))
    found, _ = load_calibration([tmp_path / "left.yaml", tmp_path / "right.yaml"])
    for camera, given in ((found.cam0, rig.cam0), (found.cam1, rig.cam1)):
        assert camera.distortion_model == model
        assert camera.distortion == (0.0, 0.0, 0.0, 0.0)
        np.testing.assert_allclose(camera.K, given.K, atol=1e-9)
    np.testing.assert_allclose(found.T_cam1_cam0, rig.T_cam1_cam0, atol=1e-9)


def test_a_camera_info_of_the_full_sensor_on_a_binned_stream_is_refused(tmp_path: Path) -> None:
    left, right = ros_files(tmp_path, make_rig())
    data = yaml.safe_load(right.read_text())
    data["image_width"], data["image_height"] = 360, 270  # the stream, 2x2 binned
    right.write_text(yaml.safe_dump(data))
    with pytest.raises(RectifyError, match=rf"^{right}: principal point \(358, 271\) is not"):
        load_calibration([left, right])


def test_ros_pair_with_explicit_extrinsic(tmp_path: Path) -> None:
    rig = make_rig("equidistant", rotated=True)
    left, right = ros_files(tmp_path, rig)
    for name in ("left", "right"):  # unrectified camera_info: no baseline in P
        data = yaml.safe_load((tmp_path / f"{name}.yaml").read_text())
        del data["rectification_matrix"], data["projection_matrix"]
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(RectifyError, match="give the extrinsic as a third file"):
        load_calibration([left, right])
    extrinsic = tmp_path / "extrinsic.yaml"
    extrinsic.write_text(yaml.safe_dump({"T_cam1_cam0": rig.T_cam1_cam0.tolist()}))
    found, source = load_calibration([left, right, extrinsic])
    assert_same_rig(found, rig)
    assert "extrinsic from" in source and "extrinsic.yaml" in source
    extrinsic.write_text(yaml.safe_dump({"R": rig.R.tolist(), "T": rig.t.tolist()}))
    assert_same_rig(load_calibration([left, right, extrinsic])[0], rig)


@pytest.mark.parametrize("told_by", ["paths", "camera_name", "projection_matrix"])
def test_ros_pair_given_right_camera_first_is_refused(tmp_path: Path, told_by: str) -> None:
    # each camera was rectified with the other's calibration, the extrinsic inverted, unsaid
    rig = make_rig()
    left, right = ros_files(tmp_path, rig)
    tx = [
        yaml.safe_load(path.read_text())["projection_matrix"]["data"][3] for path in (left, right)
    ]
    assert tx[0] == 0 and tx[1] < 0  # as camera_calibration writes them: Tx = -fx' B on the right
    first, second = right, left
    if told_by != "paths":  # paths that say nothing: the names tell, else the matrices
        first, second = tmp_path / "a.yaml", tmp_path / "b.yaml"
        for source, target, name in ((right, first, "right"), (left, second, "left")):
            data = yaml.safe_load(source.read_text())
            data["camera_name"] = f"narrow_stereo/{name}" if told_by == "camera_name" else "cam"
            target.write_text(yaml.safe_dump(data, sort_keys=False))
    said = {
        "paths": "the right camera's and the second the left camera's",
        "camera_name": "'narrow_stereo/right' and the second 'narrow_stereo/left'",
        "projection_matrix": f"the right camera's (Tx = {tx[1]:g}, the baseline) and the second "
        "the left's (Tx = 0)",
    }[told_by]
    expected = f"{first} + {second}: by their {told_by} the first is {said}; give the "
    extrinsic = tmp_path / "extrinsic.yaml"
    extrinsic.write_text(yaml.safe_dump({"T_cam1_cam0": rig.T_cam1_cam0.tolist()}))
    for files in ([first, second], [first, second, extrinsic]):
        with pytest.raises(RectifyError, match=rf"^{re.escape(expected)}.* order cam0, cam1"):
            load_calibration(files)
    found, _ = load_calibration([second, first])  # the left camera's first: read
    assert_same_rig(found, rig)


def test_nan_is_a_one_line_error_naming_the_file(tmp_path: Path) -> None:
    rig = make_rig()
    keys = {**opencv_stereo_keys(rig), "image_size": np.array([720, 540])}
    keys["K2"] = np.array([[np.nan, 0, 360], [0, 350, 270], [0, 0, 1]])
    path = write_storage(tmp_path / "nan.yml", keys)
    with pytest.raises(RectifyError, match=r"nan\.yml: K2 is empty or contains NaN") as info:
        load_calibration([path])
    assert "\n" not in str(info.value)

    left, right = ros_files(tmp_path, rig)
    right.write_text(right.read_text().replace("352.0", ".nan", 1))
    with pytest.raises(RectifyError, match=r"right\.yaml: camera_matrix is empty or contains NaN"):
        load_calibration([left, right])

    write_kalibr(tmp_path / "camchain.yaml", rig)
    camchain = tmp_path / "camchain.yaml"
    camchain.write_text(camchain.read_text().replace("350.0", ".nan", 1))
    with pytest.raises(
        RectifyError, match=r"camchain\.yaml: cam0\.intrinsics: camera parameters must be finite"
    ):
        load_calibration([camchain])


def test_unknown_format_lists_the_supported_ones(tmp_path: Path) -> None:
    path = tmp_path / "other.yaml"
    path.write_text("hello: world\n")
    with pytest.raises(RectifyError, match="not a recognised calibration; expected one Kalibr"):
        load_calibration([path])
    with pytest.raises(RectifyError, match=r"missing\.yaml: file not found"):
        load_calibration([tmp_path / "missing.yaml"])


def test_euroc_sensor_files_give_the_rig_and_a_bad_pose_names_its_file(tmp_path: Path) -> None:
    from lenspair.simulate.euroc import write_sensor_yaml

    rig = make_rig("equidistant", rotated=True)
    files = [tmp_path / "cam0.yaml", tmp_path / "cam1.yaml"]
    write_sensor_yaml(files[0], rig.cam0, np.eye(4), 20.0, "cam0")
    write_sensor_yaml(files[1], rig.cam1, np.linalg.inv(rig.T_cam1_cam0), 20.0, "cam1")
    found, source = load_calibration(files)
    assert source.startswith("EuRoC sensor.yaml")
    assert found.cam0 == rig.cam0 and found.cam1 == rig.cam1
    np.testing.assert_allclose(found.T_cam1_cam0, rig.T_cam1_cam0, atol=1e-12)
    # given cam1 first, each camera was rectified with the other's intrinsics, unsaid
    with pytest.raises(RectifyError, match=r"the first is cam1's .* order cam0, cam1"):
        load_calibration(files[::-1])
    text = files[1].read_text()
    files[1].write_text(text.replace("  data: [", "  data: [7, "))  # 17 numbers
    with pytest.raises(RectifyError, match=rf"^{files[1]}: T_BS: expected 16 numbers"):
        load_calibration(files)
    zeros = "  data: [" + ", ".join(["0"] * 16) + "]"  # a placeholder pose: LinAlgError
    files[1].write_text(
        "\n".join(zeros if "  data:" in line else line for line in text.split("\n"))
    )
    with pytest.raises(RectifyError, match=rf"^{files[1]}: T_BS is not a rigid transform"):
        load_calibration(files)
    lines = text.split("\n")
    files[1].write_text(
        "\n".join(line for line in lines if "T_BS" not in line and not line.startswith("  "))
    )
    with pytest.raises(RectifyError, match=rf"^{files[1]}: missing key 'T_BS'"):
        load_calibration(files)  # it said "not a recognised calibration", naming no key
    # a lens model named in EuRoC's words is refused in them (not Kalibr's "radtan")
    files[1].write_text(text.replace("radial-tangential", "fov").replace("equidistant", "fov"))
    with pytest.raises(
        RectifyError,
        match=rf"^{files[1]}: distortion_model: expected radial-tangential or equidistant, "
        "got 'fov'",
    ):
        load_calibration(files)


def test_euroc_radtan_with_a_zero_k3_is_read_and_a_non_zero_one_refused(tmp_path: Path) -> None:
    from lenspair.simulate.euroc import write_sensor_yaml

    rig = make_rig("radtan")
    files = [tmp_path / "cam0.yaml", tmp_path / "cam1.yaml"]
    write_sensor_yaml(files[0], rig.cam0, np.eye(4), 20.0, "cam0")
    write_sensor_yaml(files[1], rig.cam1, np.linalg.inv(rig.T_cam1_cam0), 20.0, "cam1")
    text = files[0].read_text()
    files[0].write_text(_with_k3(text, "0.0"))
    found, _ = load_calibration(files)
    assert found.cam0 == rig.cam0
    files[0].write_text(_with_k3(text, "0.01"))
    with pytest.raises(RectifyError, match=rf"^{files[0]}: distortion_coefficients: a non-zero k3"):
        load_calibration(files)


def _with_k3(text: str, k3: str) -> str:
    lines = text.split("\n")
    for index, line in enumerate(lines):
        if line.startswith("distortion_coefficients: ["):
            lines[index] = line.rstrip("]") + f", {k3}]"
    return "\n".join(lines)


def _single_camera_files(folder: Path, rig: StereoRig, matrix_first: bool = False) -> list[Path]:
    paths = []
    for name, camera in (("cam0", rig.cam0), ("cam1", rig.cam1)):
        size = {"image_width": 720, "image_height": 540}
        matrices = {"camera_matrix": camera.K, "distortion_coefficients": camera.dist_coeffs}
        values = {**matrices, **size} if matrix_first else {**size, **matrices}
        paths.append(write_storage(folder / f"{name}.yml", values))
    return paths


@pytest.mark.parametrize("matrix_first", [False, True])
def test_per_camera_opencv_files_given_cam1_first_are_refused(
    tmp_path: Path, matrix_first: bool
) -> None:
    # with the matrices first, the files' values compare as arrays first (which cannot be
    # compared with `==`): the files are told apart by position, not by value
    rig = make_rig()
    cam0, cam1 = _single_camera_files(tmp_path, rig, matrix_first)
    extrinsic = write_storage(tmp_path / "extr.yml", {"R": rig.R, "T": rig.t})
    found, _ = load_calibration([cam0, cam1, extrinsic])
    assert_same_rig(found, rig)
    with pytest.raises(RectifyError, match=r"first is cam1's and the second cam0's"):
        load_calibration([cam1, cam0, extrinsic])


def test_a_broken_opencv_file_is_one_line_naming_it(tmp_path: Path) -> None:
    rig = make_rig()
    keys = {**opencv_stereo_keys(rig), "image_size": np.array([720, 540])}
    whole = write_storage(tmp_path / "stereo.yml", keys).read_text()
    cut = tmp_path / "cut.yml"
    cut.write_text(whole[: whole.index("data:", whole.index("D1")) + 12])  # mid "data: [..."
    with pytest.raises(RectifyError, match=r"cut\.yml: not a readable OpenCV FileStorage") as e:
        load_calibration([cut])
    assert "\n" not in str(e.value)
    # a map that is not a matrix (metadata a tool wrote) is passed over, not fatal
    storage = cv2.FileStorage(str(tmp_path / "meta.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in keys.items():
        storage.write(key, value)
    storage.startWriteStruct("meta", cv2.FileNode_MAP)
    storage.write("board_width", 9)
    storage.endWriteStruct()
    storage.release()
    found, _ = load_calibration([tmp_path / "meta.yml"])
    assert_same_rig(found, rig)


def test_a_3x4_extrinsic_is_read_and_a_bad_one_named(tmp_path: Path) -> None:
    rig = make_rig()
    cam0, cam1 = _single_camera_files(tmp_path, rig)
    extrinsic = write_storage(tmp_path / "extr.yml", {"T_cam1_cam0": rig.T_cam1_cam0[:3]})
    found, _ = load_calibration([cam0, cam1, extrinsic])
    assert_same_rig(found, rig)
    write_storage(extrinsic, {"T_cam1_cam0": rig.T_cam1_cam0[:2]})
    with pytest.raises(RectifyError, match=r"extr\.yml: T_cam1_cam0 must be 4x4 .*8 values"):
        load_calibration([cam0, cam1, extrinsic])


@pytest.mark.parametrize(
    ("scale", "message"), [(0.0, "sit at one point"), (1000.0, "millimetres or centimetres")]
)
def test_a_kalibr_camchain_gets_the_baseline_checks_too(
    tmp_path: Path, scale: float, message: str
) -> None:
    write_kalibr(tmp_path / "camchain.yaml", make_rig())
    data = yaml.safe_load((tmp_path / "camchain.yaml").read_text())
    for row in data["cam1"]["T_cn_cnm1"][:3]:
        row[3] *= scale
    (tmp_path / "camchain.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(RectifyError, match=rf"camchain\.yaml.*T_cn_cnm1.*{message}"):
        load_calibration([tmp_path / "camchain.yaml"])


@pytest.mark.parametrize(
    "text",
    ["%YAML:1.0\n", "%YAML:1.0\n---\n", "%YAML:1.0\n---\n- 1\n"],
    ids=["header", "empty", "list"],
)
def test_an_opencv_file_without_named_values_is_one_line_naming_it(
    tmp_path: Path, text: str
) -> None:
    # what a calibration script that stopped after opening its output leaves: an OpenCV
    # assertion (isMap) as a traceback, exit 1 ("the file system refused")
    path = tmp_path / "calib.yml"
    path.write_text(text)
    with pytest.raises(RectifyError, match=rf"^{path}: holds no named values"):
        load_calibration([path])


def test_an_opencv_matrix_with_the_wrong_count_is_named_not_passed_over(tmp_path: Path) -> None:
    rig = make_rig()
    keys = {**opencv_stereo_keys(rig), "image_size": np.array([720, 540])}
    path = write_storage(tmp_path / "stereo.yml", keys)
    text = path.read_text()
    start = text.index("data:", text.index("K1:"))
    path.write_text(text[:start] + text[start:].replace("[", "[ 1., ", 1))  # 10 values, 3x3
    # it said "no cam0 intrinsics (keys K1/M1...)", of a file that has K1
    with pytest.raises(RectifyError, match=rf"^{path}: K1: not a readable matrix"):
        load_calibration([path])


def test_ros_files_name_the_matrix_that_is_wrong(tmp_path: Path) -> None:
    rig = make_rig()
    left, right = ros_files(tmp_path, rig)
    data = yaml.safe_load(right.read_text())
    del data["camera_matrix"]["data"]
    right.write_text(yaml.safe_dump(data))
    with pytest.raises(RectifyError, match=rf"^{right}: camera_matrix: no 'data' list"):
        load_calibration([left, right])  # it said "missing key 'camera_matrix'"
    data = yaml.safe_load(ros_files(tmp_path, rig)[1].read_text())
    data["rectification_matrix"]["data"][0] = 3.0
    right.write_text(yaml.safe_dump(data))
    with pytest.raises(RectifyError, match=rf"^{right}: rectification_matrix is not a rotation"):
        load_calibration([left, right])  # it blamed T_cam1_cam0, in neither file


def test_euroc_poses_written_with_four_decimals_give_the_rig(tmp_path: Path) -> None:
    # each T_BS passed the rigid check at 1e-4; their composition was refused at 1e-5
    from lenspair.simulate.euroc import write_sensor_yaml

    rig = make_rig("equidistant", rotated=True)
    turned = np.eye(4)
    turned[:3, :3] = cv2.Rodrigues(np.array([0.2, 0.6, 0.1]))[0]
    files = [tmp_path / "cam0.yaml", tmp_path / "cam1.yaml"]
    pose0 = np.round(turned, 4)
    pose1 = np.round(turned @ np.linalg.inv(rig.T_cam1_cam0), 4)
    write_sensor_yaml(files[0], rig.cam0, pose0, 20.0, "cam0")
    write_sensor_yaml(files[1], rig.cam1, pose1, 20.0, "cam1")
    found, _ = load_calibration(files)
    rotation = found.T_cam1_cam0[:3, :3]
    assert np.abs(rotation @ rotation.T - np.eye(3)).max() < 1e-12
    np.testing.assert_allclose(found.T_cam1_cam0, rig.T_cam1_cam0, atol=5e-4)


@pytest.mark.parametrize(("y_offset", "cy"), [(412, 100.0), (0, 512.0)])
def test_a_band_read_off_the_sensors_centre_keeps_its_principal_point_outside(
    tmp_path: Path, y_offset: int, cy: float
) -> None:
    # a 1280x200 band read for frame rate: at the top of the sensor it holds no principal
    # point, which the region explains (it was refused as "not inside the 1280x200 image")
    files = []
    for name, tx in (("left", 0.0), ("right", -70.0)):
        message = {
            "header": {"frame_id": f"{name}_camera"}, "width": 1280, "height": 1024,
            "distortion_model": "plumb_bob", "d": [0.0] * 5,
            "k": [700.0, 0, 640.0, 0, 700.0, 512.0, 0, 0, 1], "r": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1],
            "p": [700.0, 0, 640.0, tx, 0, 700.0, 512.0, 0, 0, 0, 1.0, 0],
            "roi": {"x_offset": 0, "y_offset": y_offset, "width": 1280, "height": 200},
        }  # fmt: skip
        files.append(tmp_path / f"{name}.yaml")
        files[-1].write_text(yaml.safe_dump(message) + "---\n")
    rig, _ = load_calibration(files)
    assert rig.cam0.intrinsics == (700.0, 700.0, 640.0, cy)
    assert rig.cam0.resolution == (1280, 200)


def test_a_camera_info_region_needs_a_size_and_binning_divides_k() -> None:
    """ROS reads a region as the full sensor only when all four of its fields are 0; one
    with an offset and no size was read as the full sensor, its principal point shifted."""
    message = {"width": 1440, "height": 1080, "K": [700, 0, 720, 0, 700, 540, 0, 0, 1]}
    shifted = {"x_offset": 40, "y_offset": 0, "width": 0, "height": 0}
    with pytest.raises(RectifyError, match=r"/cam: camera_info roi \(40, 0, 0, 0\) has an offset"):
        message_as_camera_info({**message, "roi": shifted}, "/cam")
    binned = message_as_camera_info({**message, "binning_x": 2, "binning_y": 2}, "/cam")
    assert (binned["image_width"], binned["image_height"]) == (720, 540)
    assert binned["camera_matrix"]["data"] == [350, 0, 360, 0, 350, 270, 0, 0, 1]
