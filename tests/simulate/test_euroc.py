from pathlib import Path

import numpy as np
import pytest
import yaml

from lenspair.rectify.calib_io import load_calibration
from lenspair.rectify.rig import CameraModel
from lenspair.simulate.euroc import write_sensor_yaml

# repr() wrote 5e-05, which YAML 1.1 reads as the string "5e-05"
NUMBERS = [5e-05, 1e-07, -3e20, 2.5e-12, 1e16, 0.1, -0.002, 350.0, -2.0, 0.0]


def _camera(distortion: tuple[float, float, float, float]) -> CameraModel:
    return CameraModel((350.0, 349.5, 180.0, 135.25), "radtan", distortion, (360, 270))


@pytest.mark.parametrize("value", NUMBERS)
def test_sensor_yaml_numbers_read_back_as_the_same_numbers(tmp_path: Path, value: float) -> None:
    path = tmp_path / "sensor.yaml"
    write_sensor_yaml(path, _camera((value, 0.0, 0.0, 0.0)), np.eye(4), value, "cam0")
    data = yaml.safe_load(path.read_text())
    for read in (data["distortion_coefficients"][0], data["rate_hz"]):
        assert isinstance(read, int | float) and read == value


def test_simulated_sensor_yaml_pair_is_read_back_by_the_calibration_reader(
    tmp_path: Path,
) -> None:
    # capture-ingest falls back to sensor.yaml: it failed "expected a list of 4 numbers"
    cameras = (_camera((0.01, -0.002, 1e-04, -5e-05)), _camera((-0.03, 1e-07, 5e-05, 0.0)))
    T_body_cam1 = np.eye(4)
    T_body_cam1[0, 3] = 0.11
    files = [tmp_path / "cam0.yaml", tmp_path / "cam1.yaml"]
    write_sensor_yaml(files[0], cameras[0], np.eye(4), 20.0, "cam0")
    write_sensor_yaml(files[1], cameras[1], T_body_cam1, 20.0, "cam1")
    rig, source = load_calibration(files)
    assert source.startswith("EuRoC sensor.yaml")
    assert (rig.cam0, rig.cam1) == cameras
    np.testing.assert_allclose(rig.T_cam1_cam0[:3, 3], (-0.11, 0.0, 0.0), atol=1e-12)
