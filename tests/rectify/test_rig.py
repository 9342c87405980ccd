from pathlib import Path

import numpy as np
import pytest

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
    with pytest.raises(RectifyError, match=r"c\.yaml: cam0: camera parameters must be finite"):
        read_kalibr(tmp_path / "c.yaml")


def test_improper_rotation_is_rejected() -> None:
    T = np.eye(4)
    T[0, 0] = -1.0
    with pytest.raises(ValueError, match="proper rotation"):
        StereoRig(_rig(False).cam0, _rig(False).cam1, T)
