"""capture-ingest calibrated by a bag's own camera_info topics."""

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from lenspair.capture.bag_calibration import info_topic
from lenspair.capture.calibration_source import find_calibration
from lenspair.capture.errors import CaptureError
from lenspair.capture.ingest import ingest_recording
from lenspair.capture.recording import open_recording
from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.core.imageio import read_image
from lenspair.rectify.rig import StereoRig, write_kalibr
from tests.capture.ingest_helpers import frame_files, make_recording, rig

SIZE = (240, 160)
LEFT, RIGHT = "/stereo/left", "/stereo/right"
IMAGE = "sensor_msgs/msg/Image"


def _camera_info(stereo: StereoRig) -> list[dict[str, Any]]:
    """The two cameras' CameraInfo fields as camera_calibration fills them (OpenCV's rectify)."""
    matrices, coefficients = [], []
    for camera in (stereo.cam0, stereo.cam1):
        fx, fy, cx, cy = camera.intrinsics
        matrices.append(np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]]))
        coefficients.append(np.array([*camera.distortion, 0.0]))
    R, T = stereo.T_cam1_cam0[:3, :3].copy(), stereo.T_cam1_cam0[:3, 3].reshape(3, 1).copy()
    R0, R1, P0, P1, *_ = cv2.stereoRectify(
        matrices[0], coefficients[0], matrices[1], coefficients[1], stereo.cam0.resolution, R, T
    )
    width, height = stereo.cam0.resolution
    return [
        {
            "height": height,
            "width": width,
            "distortion_model": "plumb_bob",
            "D": d,
            "K": k.reshape(-1),
            "R": r.reshape(-1),
            "P": p.reshape(-1),
        }
        for k, d, r, p in (
            (matrices[0], coefficients[0], R0, P0),
            (matrices[1], coefficients[1], R1, P1),
        )
    ]


def _bag(tmp_path: Path, kind: str, infos: list[dict[str, Any]] | None) -> Path:
    """A stereo bag of a simulated rain recording, with camera_info beside each camera."""
    euroc = make_recording(tmp_path / "euroc", frames=4, camchain=False)
    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    types = store.types
    folder = tmp_path / "bags"
    folder.mkdir()
    write_rig_file(folder / "rig.yaml", RigFile(obstructed="cam1", anomaly=("rain",)))
    bag = folder / "run.bag" if kind == "ros1" else folder / "run"
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    writer: Any = Writer1(bag) if kind == "ros1" else Writer2(bag, version=9, storage_plugin=plugin)

    def serialize(message: Any, msgtype: str) -> bytes:
        if kind == "ros1":
            return bytes(store.serialize_ros1(message, msgtype))
        return bytes(store.serialize_cdr(message, msgtype))

    with writer:
        for side, camera in ((LEFT, "cam0"), (RIGHT, "cam1")):
            image = writer.add_connection(
                f"{side}/image_raw", "sensor_msgs/msg/Image", typestore=store
            )
            info = writer.add_connection(
                f"{side}/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store
            )
            for path in frame_files(euroc, camera):
                t_ns = int(path.stem)
                stamp = types["builtin_interfaces/msg/Time"](
                    sec=t_ns // 10**9, nanosec=t_ns % 10**9
                )
                extra = {"seq": 0} if kind == "ros1" else {}
                header = types["std_msgs/msg/Header"](stamp=stamp, frame_id=camera, **extra)
                pixels = read_image(path)
                message = types[IMAGE](
                    header=header, height=pixels.shape[0], width=pixels.shape[1],
                    encoding="mono8", is_bigendian=0, step=pixels.shape[1], data=pixels.reshape(-1),
                )  # fmt: skip
                writer.write(image, t_ns, serialize(message, IMAGE))
                if infos is None:
                    continue
                fields = infos[0 if camera == "cam0" else 1]
                if kind != "ros1":
                    fields = {k.lower() if len(k) == 1 else k: v for k, v in fields.items()}
                region = {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0}
                region |= fields.get("roi", {})
                roi = types["sensor_msgs/msg/RegionOfInterest"](**region, do_rectify=False)
                binned = {"binning_x": 0, "binning_y": 0} | {
                    k: v for k, v in fields.items() if k.startswith("binning")
                }
                info_message = types["sensor_msgs/msg/CameraInfo"](
                    header=header, roi=roi, **binned,
                    **{k: np.asarray(v, np.float64) if k.lower() in "dkrp" else v
                       for k, v in fields.items() if k != "roi" and not k.startswith("binning")},
                )  # fmt: skip
                writer.write(info, t_ns, serialize(info_message, "sensor_msgs/msg/CameraInfo"))
    return bag


def test_the_camera_info_of_a_camera_is_found_beside_its_images() -> None:
    infos = {"/stereo/left/camera_info", "/zed/left/camera_info"}
    assert info_topic("/stereo/left/image_raw", infos) == "/stereo/left/camera_info"
    assert info_topic("/stereo/left/image_raw/compressed", infos) == "/stereo/left/camera_info"
    assert info_topic("/zed/left/image_rect_color", infos) == "/zed/left/camera_info"
    assert info_topic("/stereo/right/image_raw", infos) is None


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_a_bag_without_a_calibration_file_is_calibrated_by_its_camera_info(
    tmp_path: Path, kind: str
) -> None:
    # it was "no calibration: pass --calib FILE", though the bag held the driver's calibration
    bag = _bag(tmp_path, kind, _camera_info(rig()))
    recording = open_recording(bag)
    found, source = find_calibration(recording, RigFile("cam1"), ())
    assert source.startswith(
        f"ROS camera_info {bag}:{LEFT}/camera_info + {bag}:{RIGHT}/camera_info"
    )
    np.testing.assert_allclose(found.T_cam1_cam0, rig().T_cam1_cam0, atol=1e-12)
    assert found.cam0.intrinsics == rig().cam0.intrinsics
    report = ingest_recording(bag, tmp_path / "out", size=SIZE, workers=1)
    # as calibrated by the camchain the simulation was made with
    write_kalibr(bag.parent / "camchain.yaml", rig())
    by_file = ingest_recording(bag, tmp_path / "out_file", size=SIZE, workers=1)
    assert by_file.calibration_source.endswith("camchain.yaml")
    assert report.counts["kept"] == by_file.counts["kept"] == 4
    np.testing.assert_allclose(report.crop, by_file.crop)


def _on_the_sensor(info: dict[str, Any], binning: int, offset: tuple[int, int]) -> dict[str, Any]:
    """``info`` as a camera binning ``binning`` x ``binning`` sensor pixels, read from a region
    at ``offset`` (sensor pixels), reports it: K and P of the full sensor, image_geometry's rule."""
    k, p = np.array(info["K"], float).reshape(3, 3), np.array(info["P"], float).reshape(3, 4)
    for matrix in (k, p):
        matrix[:2] *= binning
        matrix[:2, 2] += offset
    width, height = info["width"] * binning, info["height"] * binning
    sensor = {"width": width + 2 * offset[0], "height": height + 2 * offset[1]}
    roi = {"x_offset": offset[0], "y_offset": offset[1], "width": width, "height": height}
    return {**info, **sensor, "K": k.reshape(-1), "P": p.reshape(-1), "roi": roi,
            "binning_x": binning, "binning_y": binning}  # fmt: skip


@pytest.mark.parametrize(("binning", "offset"), [(2, (0, 0)), (1, (40, 24)), (2, (80, 48))])
def test_camera_info_of_a_binning_or_cropping_camera_is_taken_to_its_images(
    tmp_path: Path, binning: int, offset: tuple[int, int]
) -> None:
    """K and P describe the full sensor: a 2x2-binned camera's bag was refused, "the
    calibration says 480x320" for its 240x160 images."""
    infos = [_on_the_sensor(info, binning, offset) for info in _camera_info(rig())]
    bag = _bag(tmp_path, "ros2", infos)
    found, _ = find_calibration(open_recording(bag), RigFile("cam1"), ())
    for camera, true in ((found.cam0, rig().cam0), (found.cam1, rig().cam1)):
        assert camera.resolution == true.resolution
        np.testing.assert_allclose(camera.intrinsics, true.intrinsics, atol=1e-9)
    np.testing.assert_allclose(found.T_cam1_cam0, rig().T_cam1_cam0, atol=1e-9)
    report = ingest_recording(bag, tmp_path / "out", size=SIZE, workers=1)
    assert report.counts["kept"] == 4


def test_a_driver_never_calibrated_is_named_and_told_to_pass_calib(tmp_path: Path) -> None:
    zeros = [{**info, "K": np.zeros(9), "P": np.zeros(12)} for info in _camera_info(rig())]
    bag = _bag(tmp_path, "ros1", zeros)
    with pytest.raises(CaptureError) as caught:
        find_calibration(open_recording(bag), RigFile("cam1"), ())
    (line,) = str(caught.value).splitlines()
    assert line.startswith(f"{bag}:{LEFT}/camera_info: ")
    assert line.endswith("(the bag's camera_info holds no usable calibration: pass --calib FILE)")


def test_a_bag_without_camera_info_says_so(tmp_path: Path) -> None:
    bag = _bag(tmp_path, "ros1", None)
    with pytest.raises(CaptureError, match=r"no calibration \(no camera_info topic beside"):
        find_calibration(open_recording(bag), RigFile("cam1"), ())
