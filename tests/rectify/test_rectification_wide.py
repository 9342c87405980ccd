"""Rectifying fisheye rigs whose corners see past 90 deg (a diagonal field over 180 deg).

A pinhole view spreads rays near 90 deg over an unbounded plane: the raw
border ran out to infinity along the diagonals and the zoom search put the
rectified view there (a focal length of a few pixels, its centre thousands
of pixels off), so ``capture-ingest`` found no feature matches.
"""

from pathlib import Path

import numpy as np
import pytest
import yaml

from lenspair.capture.ingested import read_pairs
from lenspair.cli import main
from lenspair.rectify import outline
from lenspair.rectify.outline import MAX_ANGLE_DEG
from lenspair.rectify.rectification import StereoRectification
from lenspair.rectify.rig import CameraModel, StereoRig
from lenspair.simulate.transforms import rotation_xyz_deg
from tests.capture.ingest_helpers import registration_errors

SAMPLES = Path(__file__).resolve().parents[2] / "calib_samples"
F_WIDE = 280.0  # 720x540: the corners at 92 deg off-axis, the side edges at 74 deg


def _rig(f: float) -> StereoRig:
    camera = CameraModel((f, f, 359.5, 269.5), "equidistant", (0.0, 0.0, 0.0, 0.0), (720, 540))
    turn = rotation_xyz_deg((0.3, -0.4, 0.2))
    T = np.eye(4)
    T[:3, :3] = turn
    T[:3, 3] = turn @ np.array([-0.11, 0.0, 0.0])
    return StereoRig(camera, camera, T)


@pytest.mark.parametrize("f", [F_WIDE, 260.0])
def test_a_lens_seeing_past_90_deg_in_its_corners_rectifies_about_its_centre(f: float) -> None:
    rectification = StereoRectification.from_rig(_rig(f))
    K = rectification.K
    assert abs(K[0, 2] - 359.5) < 20 and abs(K[1, 2] - 269.5) < 20
    # the view within the side edges' field (74 deg at f 280), not a sliver of it
    assert 0.5 * f < K[0, 0] < f
    # every rectified border pixel has its source inside both raw images
    width, height = rectification.size
    xs, ys = np.meshgrid(np.arange(width), [0, height - 1])
    border = np.concatenate(
        [np.column_stack([xs.ravel(), ys.ravel()]), [[0, y] for y in range(height)]]
    ).astype(np.float64)
    for view in ("cam0", "cam1"):
        raw = rectification.rectified_to_raw(view, border)  # type: ignore[arg-type]
        assert np.isfinite(raw).all()
        assert (raw >= -0.5).all() and (raw[:, 0] <= 719.5).all() and (raw[:, 1] <= 539.5).all()


def test_a_lens_within_the_cap_rectifies_as_without_it(monkeypatch: pytest.MonkeyPatch) -> None:
    # the sample rig's corners lie within the cap: its border is not moved
    assert np.degrees(np.hypot(360, 270) / 350) < MAX_ANGLE_DEG
    capped = StereoRectification.from_rig(_rig(350.0)).K
    monkeypatch.setattr(outline, "MAX_ANGLE_DEG", 89.9)
    np.testing.assert_array_equal(StereoRectification.from_rig(_rig(350.0)).K, capped)


T265 = (-0.008, 0.045, -0.043, 0.008)
"""A RealSense T265's published equidistant coefficients (848x800, f about 286 px)."""


@pytest.mark.parametrize(
    ("f", "distortion"), [(286.0, T265), (300.0, T265), (250.0, (0.02, 0.0, 0.0, 0.0))]
)
def test_a_lens_seeing_past_90_deg_on_whole_edges_rectifies_within_the_cap(
    f: float, distortion: tuple[float, float, float, float]
) -> None:
    # at f 286 the T265's side edges lie wholly past 90 deg: it was refused ("no pixel on
    # cam0's left and right edges has a valid ray"); at f 300 it rectified to an 87 deg
    # view of focal length 70 px, every border pixel found in the ring near 90 deg. A lens
    # whose distortion widens near the rim (k1 > 0) puts 90 deg past the distorted angle
    # OpenCV inverts (pi / 2): pulled onto 89.9 deg, its edges still had no ray
    camera = CameraModel((f, f, 423.5, 399.5), "equidistant", distortion, (848, 800))
    T = np.eye(4)
    T[0, 3] = -0.064
    rectified = StereoRectification.from_rig(StereoRig(camera, camera, T))
    width, height = rectified.size
    K = rectified.K
    corner = np.hypot(max(K[0, 2], width - 1 - K[0, 2]), max(K[1, 2], height - 1 - K[1, 2]))
    reach = np.degrees(np.arctan(corner / K[0, 0]))
    assert MAX_ANGLE_DEG - 0.5 < reach <= MAX_ANGLE_DEG + 1e-6  # as wide as the cap, no wider
    assert abs(K[0, 2] - 423.5) < 5 and abs(K[1, 2] - 399.5) < 5
    xs, ys = np.meshgrid(np.arange(0, width, 7), np.arange(0, height, 7))
    grid = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    for view in ("cam0", "cam1"):
        raw = rectified.rectified_to_raw(view, grid)  # type: ignore[arg-type]
        assert np.isfinite(raw).all() and (raw >= -0.5).all()
        assert (raw[:, 0] <= 847.5).all() and (raw[:, 1] <= 799.5).all()


def test_a_recording_through_a_lens_seeing_past_90_deg_is_ingested_and_registered(
    tmp_path: Path,
) -> None:
    spec = yaml.safe_load((SAMPLES / "rain.yaml").read_text())
    for camera in ("cam0", "cam1"):
        spec["rig"][camera]["intrinsics"] = [F_WIDE, F_WIDE, 359.5, 269.5]
        spec["rig"][camera]["distortion"] = [0.0, 0.0, 0.0, 0.0]
    path = tmp_path / "wide.yaml"
    path.write_text(yaml.safe_dump(spec))
    recording, out = tmp_path / "wide", tmp_path / "out"
    assert main(["simulate", str(path), "--out", str(recording), "--frames", "6"]) == 0
    assert main(["capture-ingest", str(recording), "--out", str(out)]) == 0
    folder = out / "wide"
    assert any(r.status == "kept" for r in read_pairs(folder / "pairs.jsonl"))
    errors = registration_errors(recording, folder)
    assert float(np.median(np.concatenate(list(errors.values())))) < 0.25
