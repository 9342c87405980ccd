"""capture-ingest of a rig whose two cameras differ in resolution.

The dataset is sampled on the obstructed camera's pixels (its frames are
what the network restores): a clean camera of higher resolution is reduced
onto them, low-pass filtered first; one of lower resolution is enlarged,
and said so.
"""

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from lenspair.capture.ingested import read_pairs
from lenspair.cli import main
from lenspair.core.imageio import read_image
from lenspair.rectify.crop import Crop
from lenspair.rectify.remap import RemapGrid, apply, target_map

SAMPLES = Path(__file__).resolve().parents[2] / "calib_samples"
FRAMES = 6


def _simulate(tmp_path: Path, name: str, finer: str | None) -> Path:
    """The sample rain scene (cam1 obstructed), with camera ``finer`` at twice the resolution."""
    spec = yaml.safe_load((SAMPLES / "rain.yaml").read_text())
    if finer is not None:
        camera = spec["rig"][finer]
        camera["intrinsics"] = [2 * value for value in camera["intrinsics"]]
        camera["resolution"] = [1440, 1080]
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec))
    out = tmp_path / name
    assert main(["simulate", str(path), "--out", str(out), "--frames", str(FRAMES)]) == 0
    return out


def _ingest(recording: Path, out: Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    assert main(["capture-ingest", str(recording), "--out", str(out)]) == 0
    (folder,) = [path for path in out.iterdir() if (path / "pairs.jsonl").is_file()]
    images = {}
    for record in read_pairs(folder / "pairs.jsonl"):
        if record.status == "kept":
            name = f"{record.t_ns}.png"
            images[record.t_ns] = tuple(read_image(folder / k / name) for k in ("input", "target"))
    return images  # type: ignore[return-value]


def _sharpness(image: np.ndarray) -> float:
    return float(cv2.Laplacian(image.astype(np.float64), cv2.CV_64F).var())


def test_a_finer_clean_camera_leaves_the_inputs_as_a_rig_of_equal_cameras_has_them(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # the grid had cam0's size: a clean cam0 of twice the resolution enlarged every input
    equal = _ingest(_simulate(tmp_path, "equal", None), tmp_path / "out_equal")
    finer = _ingest(_simulate(tmp_path, "finer", "cam0"), tmp_path / "out_finer")
    assert equal.keys() & finer.keys()
    for t_ns in equal.keys() & finer.keys():
        difference = np.abs(equal[t_ns][0].astype(float) - finer[t_ns][0].astype(float))
        assert difference.mean() < 0.5  # the same obstructed camera: the same inputs
        # the target, reduced 2x, is neither aliased nor blurred to the equal rig's beyond
        ratio = _sharpness(finer[t_ns][1]) / _sharpness(equal[t_ns][1])
        assert 0.7 < ratio < 2.5
    # its side check is not misled by the finer camera's lower detail per pixel
    assert not any("but cam1 is declared" in m for m in caplog.messages)


def test_a_coarser_clean_camera_is_enlarged_onto_a_finer_obstructed_ones_pixels_and_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    finer = _ingest(_simulate(tmp_path, "finer", "cam1"), tmp_path / "out")
    inputs = [pair[0] for pair in finer.values()]
    raw = sorted((tmp_path / "finer" / "mav0" / "cam1" / "data").glob("*.png"))
    # on the obstructed camera's own scale: about its raw frames' detail, not 2.5x it
    # (a grid of cam0's size reduced the inputs with a bicubic kernel alone: aliased)
    ratio = np.median([_sharpness(i) for i in inputs]) / _sharpness(read_image(raw[0]))
    assert 0.5 < ratio < 1.6
    assert any("the clean camera cam0 is enlarged" in m for m in caplog.messages)


def test_a_view_reduced_by_a_map_is_low_pass_filtered_not_aliased() -> None:
    # a fine pattern reduced 2.5x: bicubic taps alone alias it into coarse bands
    rng = np.random.default_rng(0)
    image = (rng.random((500, 500)) > 0.5).astype(np.uint8) * 255
    crop_size = (160, 160)

    def reduced(points: np.ndarray) -> np.ndarray:
        return points * 2.5 + 40.0

    grid = target_map(reduced, np.eye(3), Crop(0, 0, *crop_size))
    assert grid.levels == 1 and grid.step == pytest.approx(2.5)
    out = apply(image, grid).astype(float)
    whole = RemapGrid(grid.map_x * 2, grid.map_y * 2)  # the same map without the pyramid
    aliased = apply(image, whole).astype(float)
    expected = cv2.blur(image.astype(float), (3, 3))[40:440:5, 40:440:5]  # the local mean
    assert out.std() < 0.6 * aliased.std()
    assert np.abs(out[::2, ::2] - expected).mean() < np.abs(aliased[::2, ::2] - expected).mean()
