"""Helpers of the ingest tests: hand-made recordings, and simulator ground truth.

Two ideal pinhole cameras side by side (no distortion, no rotation), looking
at a textured plane: cam1's image is cam0's shifted by ``DISPARITY`` px, so
the true clean -> obstructed homography is a pure shift. The obstructed
camera gets disk-shaped "drops" showing a flipped view of the scene.
"""

import json
import re
from pathlib import Path

import cv2
import numpy as np

from lenspair.capture.ingested import read_pairs, read_report
from lenspair.capture.rigfile import RigFile, write_rig_file
from lenspair.core.imagewrite import write_image
from lenspair.rectify.projection import pixel_rays, project_rays
from lenspair.rectify.rectification import on_camera
from lenspair.rectify.remap import apply_homography, pixel_grid
from lenspair.rectify.rig import CameraModel, StereoRig, read_kalibr, write_kalibr
from tests.images import texture

T0 = 1_700_000_000_000_000_000
PERIOD_NS = 50_000_000
WIDTH, HEIGHT = 320, 240
DISPARITY = 2
CROP = "240x160"


def add_drops(image: np.ndarray, rng: np.random.Generator, count: int) -> np.ndarray:
    """Soft disks showing a flipped, blurred view of the scene (defocused drops)."""
    out = image.copy()
    h, w = image.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    for _ in range(count):
        cx, cy, r = rng.uniform(0, w), rng.uniform(0, h), rng.uniform(5, 14)
        disk = ((xs - cx) ** 2 + (ys - cy) ** 2 < r * r).astype(np.float32)
        alpha = cv2.GaussianBlur(disk, (0, 0), 2.0)  # out of focus: soft rim
        sx = np.clip(cx - 0.5 * (xs - cx), 0, w - 1)
        sy = np.clip(cy - 0.5 * (ys - cy), 0, h - 1)
        flipped = cv2.GaussianBlur(cv2.remap(image, sx, sy, cv2.INTER_LINEAR), (0, 0), 3)
        out = (1 - alpha) * out + alpha * (0.8 * flipped + 0.1)
    return out


def rig(width: int = WIDTH, height: int = HEIGHT) -> StereoRig:
    """The ideal rig: cam1 0.11 m to the right of cam0."""
    camera = CameraModel(
        (300.0, 300.0, (width - 1) / 2, (height - 1) / 2), "radtan", (0.0,) * 4, (width, height)
    )
    T = np.eye(4)
    T[0, 3] = -0.11
    return StereoRig(camera, camera, T)


def make_recording(
    root: Path,
    frames: int = 4,
    obstructed: str = "cam1",
    dtype: type = np.uint8,
    drops: int = 12,
    camchain: bool = True,
    colour: bool = False,
) -> Path:
    """Write an EuRoC recording with rig.yaml and camchain.yaml; returns its folder."""
    scene = texture((HEIGHT + 40, WIDTH + 6 * frames + 40), seed=5)
    rng = np.random.default_rng(9)
    top = np.iinfo(dtype).max
    for camera in ("cam0", "cam1"):
        (root / "mav0" / camera / "data").mkdir(parents=True, exist_ok=True)
    rows: dict[str, list[str]] = {"cam0": [], "cam1": []}
    for i in range(frames):
        left = 20 + 6 * i
        views = {
            "cam0": scene[20 : 20 + HEIGHT, left : left + WIDTH],
            "cam1": scene[20 : 20 + HEIGHT, left + DISPARITY : left + DISPARITY + WIDTH],
        }
        views[obstructed] = add_drops(views[obstructed], rng, drops)
        for camera, view in views.items():
            t_ns = T0 + i * PERIOD_NS + (100_000 if camera == "cam1" else 0)
            gain = 0.85 if camera == "cam0" else 1.0  # the cameras differ in exposure
            pixels = np.rint(np.clip(view * gain, 0, 1) * top).astype(dtype)
            if colour:  # a tinted RGB version of the same scene
                pixels = np.ascontiguousarray(
                    np.stack(
                        [pixels, (pixels * 0.9).astype(dtype), (pixels * 0.7).astype(dtype)], -1
                    )
                )
            write_image(root / "mav0" / camera / "data" / f"{t_ns}.png", pixels)
            rows[camera].append(f"{t_ns},{t_ns}.png")
    for camera, lines in rows.items():
        text = "#timestamp [ns],filename\n" + "".join(line + "\n" for line in lines)
        (root / "mav0" / camera / "data.csv").write_text(text)
    write_rig_file(root / "rig.yaml", RigFile(obstructed=obstructed, anomaly=("rain",)))  # type: ignore[arg-type]
    if camchain:
        write_kalibr(root / "camchain.yaml", rig())
    return root


def frame_files(root: Path, camera: str) -> list[Path]:
    """Image files of one camera, in time order."""
    return sorted((root / "mav0" / camera / "data").glob("*.png"))


# -- ground truth of simulated recordings ---------------------------------------------


def simulate(scene: str, out: Path, frames: int) -> Path:
    """``lenspair simulate calib_samples/<scene>.yaml --out out --frames N``; returns ``out``."""
    from lenspair.cli import main

    samples = Path(__file__).resolve().parents[2] / "calib_samples"
    assert (
        main(
            ["simulate", str(samples / f"{scene}.yaml"), "--out", str(out), "--frames", str(frames)]
        )
        == 0
    )
    return out


def _refinement(reason: str | None) -> np.ndarray:
    match = re.search(r"refined: target shifted by \(([-\d.]+), ([-\d.]+)\) px", reason or "")
    return np.array([float(match.group(1)), float(match.group(2))]) if match else np.zeros(2)


def registration_errors(recording: Path, out_dir: Path, step: int = 7) -> dict[int, np.ndarray]:
    """Registration error of every kept frame, raw clean pixels, on a grid of output pixels.

    For an output pixel ``u``, the composed target map samples the raw clean
    image at ``m(u)``. The truth: the raw obstructed pixel the input map
    samples for ``u`` (exact: the true calibration is used), undistorted with
    the obstructed camera, sent through the simulator's true far-plane
    homography of that frame, and distorted with the clean camera, gives
    ``m*(u)``. The error is ``|m(u) - m*(u)|`` in raw clean pixels
    (every ``step``-th output pixel).
    """
    report = read_report(out_dir / "report.json")
    matrix = np.asarray(json.loads((out_dir / "registration.json").read_text())["matrix"])
    stereo = read_kalibr(recording / "camchain.yaml")
    obstructed = report.obstructed
    rectification = on_camera(stereo, obstructed)  # type: ignore[arg-type]
    truth = json.loads((recording / "truth" / "geometry.json").read_text())
    clean = "cam0" if obstructed == "cam1" else "cam1"
    frames = {f[obstructed]["t_ns"]: f for f in truth["frames"]}
    K_obstructed, K_clean = np.asarray(truth["K_obstructed"]), np.asarray(truth["K_clean"])
    x0, y0, width, height = report.crop
    grid = pixel_grid(x0, y0, width, height)[::step]
    raw_obstructed = rectification.rectified_to_raw(obstructed, grid).astype(np.float64)  # type: ignore[arg-type]
    pinhole = pixel_rays(stereo.camera(obstructed), raw_obstructed) @ K_obstructed.T
    errors = {}
    for record in read_pairs(out_dir / "pairs.jsonl"):
        if record.status != "kept":
            continue
        true_h = np.asarray(frames[record.t_ns]["homography"])
        clean_pinhole = apply_homography(np.linalg.inv(true_h), pinhole[:, :2] / pinhole[:, 2:])
        rays = np.column_stack([clean_pinhole, np.ones(len(grid))]) @ np.linalg.inv(K_clean).T
        expected = project_rays(stereo.camera(clean), rays)
        ours = rectification.rectified_to_raw(
            clean,  # type: ignore[arg-type]
            apply_homography(np.linalg.inv(matrix), grid + _refinement(record.reason)),
        ).astype(np.float64)
        errors[record.t_ns] = np.linalg.norm(ours - expected, axis=1)
    return errors


def plane_region(recording: Path, out_dir: Path, t_ns: int, name: str) -> np.ndarray:
    """Where plane ``name`` appears in the output images of frame ``t_ns``: bool ``(H, W)``.

    The plane's corners (centre, normal and size from ``truth/geometry.json``;
    no roll about the normal) are projected into the obstructed camera,
    rectified and cropped; the quadrilateral is filled.
    """
    report = read_report(out_dir / "report.json")
    stereo = read_kalibr(recording / "camchain.yaml")
    rectification = on_camera(stereo, report.obstructed)  # type: ignore[arg-type]
    truth = json.loads((recording / "truth" / "geometry.json").read_text())
    plane = next(p for p in truth["planes"] if p["name"] == name)
    normal = np.asarray(plane["normal_world"])
    x_axis = np.cross([0.0, 1.0, 0.0], normal)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(normal, x_axis)
    half_w, half_h = np.asarray(plane["size_m"]) / 2
    centre = np.asarray(plane["centre_world"])
    corners = [
        centre + sx * half_w * x_axis + sy * half_h * y_axis
        for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    obstructed = report.obstructed
    frame = next(f for f in truth["frames"] if f[obstructed]["t_ns"] == t_ns)
    world_to_camera = np.linalg.inv(np.asarray(frame[obstructed]["T_world_cam"]))
    in_camera = (world_to_camera[:3, :3] @ np.asarray(corners).T).T + world_to_camera[:3, 3]
    raw = project_rays(stereo.camera(obstructed), in_camera)
    rectified = rectification.raw_to_rectified(obstructed, raw)  # type: ignore[arg-type]
    x0, y0, width, height = report.crop
    polygon = np.rint((rectified - [x0, y0]) * 16).astype(np.int32)
    region = np.zeros((height, width), np.uint8)
    cv2.fillPoly(region, [polygon], 1, cv2.LINE_8, 4)
    return region > 0


def tree_bytes(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden ones included): relative path -> content."""
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }
