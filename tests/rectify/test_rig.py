from pathlib import Path

import numpy as np
import pytest
import yaml

from lenspair.rectify.errors import RectifyError
from lenspair.rectify.rig import CameraModel, StereoRig, read_kalibr, write_kalibr


def _rig(rotated: bool) -> StereoRig:
    cam0 = CameraModel(
        (350.0, 351.0, 360.0, 270.0), "equidistant", (0.01, -0.002, 0.0, 0.0), (720, 540)
    )
    cam1 = CameraModel(
        (352.0, 352.5, 358.0, 271.0), "equidistant", (0.012, -0.001, 0.0, 0.0), (720, 540)
    )
    T = np.eye(4)
    T[:3, 3] = [-0.11, 0.001, 0.0]
    if rotated:
        T[:3, :3] = np.diag([-1.0, -1.0, 1.0])
    return StereoRig(cam0, cam1, T)


@pytest.mark.parametrize("rotated", [False, True])
def test_kalibr_round_trip(tmp_path: Path, rotated: bool) -> None:
    rig = _rig(rotated)
    write_kalibr(tmp_path / "camchain.yaml", rig)
    back = read_kalibr(tmp_path / "camchain.yaml")
    assert back.cam0 == rig.cam0 and back.cam1 == rig.cam1
    np.testing.assert_allclose(back.T_cam1_cam0, rig.T_cam1_cam0)
    assert back.baseline_m == pytest.approx(np.hypot(0.11, 0.001))


def test_nan_in_calibration_is_a_clear_error(tmp_path: Path) -> None:
    write_kalibr(tmp_path / "c.yaml", _rig(False))
    text = (tmp_path / "c.yaml").read_text().replace("350.0", ".nan", 1)
    (tmp_path / "c.yaml").write_text(text)
    with pytest.raises(
        RectifyError, match=r"c\.yaml: cam0\.intrinsics: camera parameters must be finite"
    ):
        read_kalibr(tmp_path / "c.yaml")


def test_improper_rotation_is_rejected() -> None:
    T = np.eye(4)
    T[0, 0] = -1.0
    with pytest.raises(ValueError, match="proper rotation"):
        StereoRig(_rig(False).cam0, _rig(False).cam1, T)


def _rotation(degrees: float) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.radians([degrees / 3, degrees, degrees / 5]))[0]


def test_a_rotation_written_with_four_decimals_is_read_as_the_nearest_rotation(
    tmp_path: Path,
) -> None:
    rig = _rig(False)
    exact = rig.T_cam1_cam0.copy()
    exact[:3, :3] = _rotation(35.0)
    camchain = tmp_path / "c.yaml"
    write_kalibr(camchain, StereoRig(rig.cam0, rig.cam1, exact))
    data = yaml.safe_load(camchain.read_text())
    data["cam1"]["T_cn_cnm1"] = np.round(exact, 4).tolist()  # ~1e-4 from orthonormal
    camchain.write_text(yaml.safe_dump(data))
    back = read_kalibr(camchain).T_cam1_cam0  # it was refused as "not a proper rotation"
    assert np.abs(back[:3, :3] @ back[:3, :3].T - np.eye(3)).max() < 1e-12
    assert np.abs(back - exact).max() < 1e-4  # the rotation meant
    # two decimals are no longer a rotation someone measured: refused, saying by how much
    data["cam1"]["T_cn_cnm1"] = np.round(exact, 2).tolist()
    camchain.write_text(yaml.safe_dump(data))
    with pytest.raises(RectifyError, match=r"c\.yaml: cam1\.T_cn_cnm1: .*not a proper rotation"):
        read_kalibr(camchain)


@pytest.mark.parametrize(
    ("key", "value", "said"),
    [
        ("resolution", [720.6, 540], r"cam0\.resolution: expected whole pixels"),
        ("intrinsics", "3503", r"cam0\.intrinsics: expected a list of 4 numbers, got '3503'"),
        ("intrinsics", [True, 350, 360, 270], r"cam0\.intrinsics: expected a list of 4 numbers"),
        ("intrinsics", [350, 351, 360], r"cam0\.intrinsics: expected 4 values, got 3"),
        ("resolution", [float("nan"), 480], r"cam0\.resolution: camera parameters must be finite"),
        ("resolution", [float("inf"), 480], r"cam0\.resolution: camera parameters must be finite"),
        ("distortion_coeffs", [0.01, 0, 0, 0, 0.2], r"cam0\.distortion_coeffs: radtan has 4"),
    ],
)
def test_a_camchain_value_of_the_wrong_kind_is_refused_not_converted(
    tmp_path: Path, key: str, value: object, said: str
) -> None:
    rig = _rig(False)
    radtan = CameraModel(rig.cam0.intrinsics, "radtan", (0.01, 0.0, 0.0, 0.0), (720, 540))
    camchain = tmp_path / "c.yaml"
    write_kalibr(camchain, StereoRig(radtan, radtan, rig.T_cam1_cam0))
    data = yaml.safe_load(camchain.read_text())
    data["cam0"][key] = value
    camchain.write_text(yaml.safe_dump(data))
    with pytest.raises(RectifyError, match=said):
        read_kalibr(camchain)


def test_a_zero_fifth_radtan_coefficient_is_read_as_the_other_readers_read_it(
    tmp_path: Path,
) -> None:
    rig = _rig(False)
    radtan = CameraModel(rig.cam0.intrinsics, "radtan", (0.01, -0.002, 0.001, 0.0), (720, 540))
    camchain = tmp_path / "c.yaml"
    write_kalibr(camchain, StereoRig(radtan, radtan, rig.T_cam1_cam0))
    data = yaml.safe_load(camchain.read_text())
    data["cam0"]["distortion_coeffs"] = [*radtan.distortion, 0.0]
    camchain.write_text(yaml.safe_dump(data))
    assert read_kalibr(camchain).cam0 == radtan


@pytest.mark.parametrize(
    ("intrinsics", "said"),
    [
        # fy typed as 4 for 400: the rectified view was made of five raw rows
        ((400.0, 4.0, 360.0, 270.0), r"fy/fx = 0\.01 \(fx 400 px, fy 4 px\)"),
        # a focal length in millimetres: a fraction of a pixel's patch, stretched
        ((3.6, 3.6, 360.0, 270.0), r"focal length 3\.6 px in a 720x540 image"),
        # the full sensor's calibration on a 2x2-binned stream: the centre in a corner
        ((700.0, 700.0, 720.0, 540.0), r"principal point \(720, 540\) is not inside"),
    ],
)
def test_intrinsics_no_camera_has_are_refused_naming_the_file(
    tmp_path: Path, intrinsics: tuple[float, float, float, float], said: str
) -> None:
    rig = _rig(False)
    camchain = tmp_path / "c.yaml"
    write_kalibr(camchain, rig)
    data = yaml.safe_load(camchain.read_text())
    data["cam1"]["intrinsics"] = list(intrinsics)
    camchain.write_text(yaml.safe_dump(data))
    with pytest.raises(RectifyError, match=rf"c\.yaml: cam1.*: {said}"):
        read_kalibr(camchain)


def test_a_baseline_of_metres_is_warned_of_as_centimetres_written_as_metres(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    rig = _rig(False)
    for baseline, warned in ((0.064, False), (6.4, True)):
        T = rig.T_cam1_cam0.copy()
        T[:3, 3] = [-baseline, 0.0, 0.0]
        write_kalibr(tmp_path / "c.yaml", StereoRig(rig.cam0, rig.cam1, T))
        caplog.clear()
        assert read_kalibr(tmp_path / "c.yaml").baseline_m == pytest.approx(baseline)
        assert ("baseline 6.4 m" in caplog.text and "centimetres" in caplog.text) == warned
