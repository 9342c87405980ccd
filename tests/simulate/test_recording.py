import hashlib
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from lenspair.capture.rigfile import read_rig_file
from lenspair.cli import main
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.rectify.rig import CameraModel, read_kalibr
from lenspair.simulate.camera import undistort_maps
from lenspair.simulate.errors import SimulateError
from lenspair.simulate.recording import simulate_recording
from lenspair.simulate.spec import load_scene

SAMPLES = Path(__file__).resolve().parents[2] / "calib_samples"
FISHEYE0 = {
    "intrinsics": [350.2, 349.8, 361.3, 268.4],
    "distortion_model": "equidistant",
    "distortion": [-0.0095, 0.0036, -0.0049, 0.0015],
}
FISHEYE1 = {
    "intrinsics": [351.6, 351.1, 357.9, 271.2],
    "distortion_model": "equidistant",
    "distortion": [-0.0089, 0.0029, -0.0042, 0.0012],
}
# Half-size cameras for tests that check bookkeeping rather than pixels.
SMALL0 = {**FISHEYE0, "intrinsics": [175.1, 174.9, 180.4, 134.0], "resolution": [360, 270]}
SMALL1 = {**FISHEYE1, "intrinsics": [175.8, 175.5, 178.7, 135.4], "resolution": [360, 270]}
SMALL = {"cam0": SMALL0, "cam1": SMALL1}
WALL = {"texture": ["astronaut", "gravel", "coffee", "brick"], "depth_m": 60.0, "tile_m": [60, 60]}


def _scene(tmp_path: Path, **sections: Any) -> dict[str, Any]:
    data: dict[str, Any] = {
        "rig": {"baseline_m": 0.11, "cam1_rotation_deg": [0.3, -0.4, 0.2], "cam0": FISHEYE0,
                "cam1": FISHEYE1},
        "planes": [WALL],
        "motion": {"velocity_mps": [0.8, 0.0, 0.0], "yaw_amplitude_deg": 1.0},
        "recording": {"frames": 3},
        "seed": 3,
    }  # fmt: skip
    for key, value in sections.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            data[key] = {**data[key], **value}
        else:
            data[key] = value
    return data


def _render(tmp_path: Path, data: dict[str, Any], name: str = "rec") -> Path:
    spec_file = tmp_path / f"{name}.yaml"
    spec_file.write_text(yaml.safe_dump(data))
    out = tmp_path / name
    simulate_recording(load_scene(spec_file), out, base_dir=tmp_path)
    return out


def _csv(out: Path, camera: str) -> list[int]:
    lines = (out / "mav0" / camera / "data.csv").read_text().splitlines()
    assert lines[0] == "#timestamp [ns],filename"
    stamps = []
    for line in lines[1:]:
        t_ns, name = line.split(",")
        assert name == f"{t_ns}.png"
        assert (out / "mav0" / camera / "data" / name).is_file()
        stamps.append(int(t_ns))
    assert stamps == sorted(stamps)
    assert len(list((out / "mav0" / camera / "data").iterdir())) == len(stamps)
    return stamps


def _geometry(out: Path) -> dict[str, Any]:
    return json.loads((out / "truth" / "geometry.json").read_text())


def _tree_digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_layout_clock_drops_and_jitter(tmp_path: Path) -> None:
    recording = {"frames": 8, "jitter_us": 300.0, "drop_probability": [0.0, 0.6]}
    out = _render(tmp_path, _scene(tmp_path, recording=recording, rig=SMALL))
    cam0, cam1 = _csv(out, "cam0"), _csv(out, "cam1")
    geometry = _geometry(out)
    frames = geometry["frames"]
    assert len(cam0) == 8 and 0 < len(cam1) < 8  # cam1 drops frames: unpaired cam0 frames
    assert cam1 == [f["cam1"]["t_ns"] for f in frames if not f["cam1"]["dropped"]]
    jitter = np.array(
        [[f[c]["t_ns"] - f["t_nominal_ns"] for c in ("cam0", "cam1")] for f in frames]
    )
    assert np.all(np.abs(jitter) <= 3 * 300_000) and np.std(jitter) > 50_000
    assert np.any(jitter[:, 0] != jitter[:, 1])  # independent per camera
    nominal = [f["t_nominal_ns"] for f in frames]
    assert np.all(np.diff(nominal) == 50_000_000)  # 20 Hz
    sensor = yaml.safe_load((out / "mav0" / "cam1" / "sensor.yaml").read_text())
    assert sensor["sensor_type"] == "camera" and sensor["camera_model"] == "pinhole"
    assert sensor["rate_hz"] == 20 and sensor["resolution"] == [360, 270]
    assert sensor["intrinsics"] == SMALL1["intrinsics"]
    assert sensor["distortion_model"] == "equidistant"
    assert sensor["distortion_coefficients"] == FISHEYE1["distortion"]
    assert len(sensor["T_BS"]["data"]) == 16
    rig = read_rig_file(out / "rig.yaml")
    assert rig.obstructed == "cam1" and rig.anomaly == () and rig.calibration == "camchain.yaml"
    assert load_scene(out / "scene.yaml").recording.frames == 8


def test_baseline_and_calibration_come_from_the_spec(tmp_path: Path) -> None:
    out = _render(tmp_path, _scene(tmp_path, rig={"baseline_m": 0.137, **SMALL}))
    rig = read_kalibr(out / "camchain.yaml")
    assert rig.baseline_m == pytest.approx(0.137, abs=1e-12)
    assert rig.cam1.intrinsics == tuple(SMALL1["intrinsics"])
    assert rig.cam0.distortion_model == "equidistant"
    T_BS = yaml.safe_load((out / "mav0" / "cam1" / "sensor.yaml").read_text())["T_BS"]["data"]
    T_body_cam1 = np.array(T_BS).reshape(4, 4)
    np.testing.assert_allclose(T_body_cam1 @ rig.T_cam1_cam0, np.eye(4), atol=1e-12)
    assert _geometry(out)["baseline_m"] == pytest.approx(0.137)


def test_no_effects_obstructed_frames_equal_clear(tmp_path: Path) -> None:
    out = _render(tmp_path, _scene(tmp_path))
    for t_ns in _csv(out, "cam1"):
        image = read_image(out / "mav0" / "cam1" / "data" / f"{t_ns}.png")
        clear = read_image(out / "truth" / "clear" / f"{t_ns}.png")
        mask = read_image(out / "truth" / "mask" / f"{t_ns}.png")
        assert image.dtype == np.uint8 and image.shape == (540, 720)
        np.testing.assert_array_equal(image, clear)
        assert mask.dtype == np.uint8 and not mask.any()
    assert len(list((out / "truth" / "clear").iterdir())) == len(_csv(out, "cam1"))


def test_effects_change_only_pixels_inside_the_mask(tmp_path: Path) -> None:
    effects = {"raindrops": {"count": 12}, "defocus": {}, "dust": {"coverage": 0.3}}
    obstructed = {"camera": "cam0", "effects": effects}
    out = _render(tmp_path, _scene(tmp_path, obstructed=obstructed))
    assert read_rig_file(out / "rig.yaml").anomaly == ("rain", "dust")
    changed = 0
    for t_ns in _csv(out, "cam0"):
        image = read_image(out / "mav0" / "cam0" / "data" / f"{t_ns}.png")
        clear = read_image(out / "truth" / "clear" / f"{t_ns}.png")
        mask = read_image(out / "truth" / "mask" / f"{t_ns}.png") > 0
        assert 0.0 < mask.mean() < 1.0
        np.testing.assert_array_equal(image[~mask], clear[~mask])
        changed += int(np.count_nonzero(image[mask] != clear[mask]))
    assert changed > 1000


def test_drops_over_light_above_full_scale_stay_saturated(tmp_path: Path) -> None:
    # a wall 20x full scale, as a sunlit sky: the camera had clipped it before the glass,
    # so drops refracted and blurred clipped light and came out grey (11 % of the footprint
    # over saturated light stayed saturated, mean code 225); one clip after the glass, as
    # a real lens, keeps 94 %
    effects = {"raindrops": {"count": 30}, "defocus": {}}
    data = _scene(
        tmp_path,
        rig=SMALL,
        planes=[{**WALL, "brightness": 20.0}],
        obstructed={"camera": "cam0", "effects": effects},
        recording={"frames": 1},
    )
    out = _render(tmp_path, data)
    (t_ns,) = _csv(out, "cam0")
    image = read_image(out / "mav0" / "cam0" / "data" / f"{t_ns}.png")
    clear = read_image(out / "truth" / "clear" / f"{t_ns}.png")
    footprint = read_image(out / "truth" / "mask" / f"{t_ns}.png") > 0
    saturated = footprint & (clear == 255)
    assert saturated.mean() > 0.1
    assert (image[saturated] == 255).mean() > 0.8


def test_effects_that_change_no_pixel_label_the_recording_clean(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # dirt too faint to move a code: the spec's labels said "dirt", the frames were clean
    effects = {"dirt": {"count": 3, "radius_px": [5.0, 10.0], "opacity": [1e-6, 2e-6]}}
    data = _scene(tmp_path, rig=SMALL, obstructed={"camera": "cam1", "effects": effects})
    with caplog.at_level("WARNING"):
        out = _render(tmp_path, data)
    for t_ns in _csv(out, "cam1"):  # the premise: no pixel changed
        image = read_image(out / "mav0" / "cam1" / "data" / f"{t_ns}.png")
        np.testing.assert_array_equal(image, read_image(out / "truth" / "clear" / f"{t_ns}.png"))
    assert read_rig_file(out / "rig.yaml").anomaly == ()
    assert any("changed no pixel" in m and "(dirt)" in m for m in caplog.messages)


def _assert_same_cam1_frames(out: Path, other: Path) -> None:
    """Every cam1 frame of ``out`` equals ``other``'s of the same time, to the bit."""
    for t_ns in _csv(out, "cam1"):
        name = Path("mav0") / "cam1" / "data" / f"{t_ns}.png"
        np.testing.assert_array_equal(read_image(out / name), read_image(other / name))


def test_a_declared_effect_that_drew_nothing_gives_no_label(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # Large dust patches at a low coverage: with seed 0 the Poisson count is 0. The frames
    # were bit-identical to the veil alone's, labelled "rain", yet rig.yaml said "dust".
    dust = {"coverage": 0.3, "scale_px": 400.0}
    veiled: dict[str, Any] = {"camera": "cam1", "effects": {"veil": {}}}
    dusty = {"camera": "cam1", "effects": {"veil": {}, "dust": dust}}
    common: dict[str, Any] = {"rig": SMALL, "recording": {"frames": 2}, "seed": 0}
    veil_only = _render(tmp_path, _scene(tmp_path, obstructed=veiled, **common), "veil")
    with caplog.at_level("WARNING"):
        out = _render(tmp_path, _scene(tmp_path, obstructed=dusty, **common), "dusty")
    _assert_same_cam1_frames(out, veil_only)  # the premise: the dust drew nothing
    assert read_rig_file(out / "rig.yaml").anomaly == ("rain",)
    assert read_rig_file(veil_only / "rig.yaml").anomaly == ("rain",)
    said = [m for m in caplog.messages if "drew nothing" in m]
    assert len(said) == 1 and "dust is declared" in said[0] and "dust.coverage" in said[0]


def test_an_effect_that_changed_no_pixel_beside_one_that_did_gives_no_label(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # drops of a thousandth of a pixel beside dust: the frames were the dust alone's to the
    # bit, yet rig.yaml said [rain, dust] (one flag for all the effects: "some changed")
    tiny = {"count": 40, "radius_px": [0.001, 0.002]}
    dust = {"coverage": 0.3, "scale_px": 20.0}
    common: dict[str, Any] = {"rig": SMALL, "recording": {"frames": 2}, "seed": 0}
    dusty = {"camera": "cam1", "effects": {"dust": dust}}
    both = {"camera": "cam1", "effects": {"raindrops": tiny, "dust": dust}}
    dust_only = _render(tmp_path, _scene(tmp_path, obstructed=dusty, **common), "dust")
    with caplog.at_level("WARNING"):
        out = _render(tmp_path, _scene(tmp_path, obstructed=both, **common), "both")
    _assert_same_cam1_frames(out, dust_only)  # the premise: the drops changed nothing
    assert read_rig_file(out / "rig.yaml").anomaly == ("dust",)
    assert any("changed no pixel" in m and "(raindrops)" in m for m in caplog.messages)
    caplog.clear()
    visible = {**both, "effects": {"raindrops": {"count": 40}, "dust": dust}}
    with caplog.at_level("WARNING"):
        out = _render(tmp_path, _scene(tmp_path, obstructed=visible, **common), "visible")
    assert read_rig_file(out / "rig.yaml").anomaly == ("rain", "dust")
    assert not caplog.messages


def test_sixteen_bit_rgb_recording(tmp_path: Path) -> None:
    out = _render(tmp_path, _scene(tmp_path, rig={"bit_depth": 16, "color": "rgb", **SMALL}))
    image = read_image(out / "mav0" / "cam0" / "data" / f"{_csv(out, 'cam0')[0]}.png")
    assert image.dtype == np.uint16 and image.shape == (270, 360, 3)
    assert len(np.unique(image)) > 1000  # uses the 16-bit range, not 8-bit steps


def test_same_seed_same_bytes_other_seed_differs(tmp_path: Path) -> None:
    data = _scene(
        tmp_path,
        recording={"frames": 3, "jitter_us": 200.0, "drop_probability": [0.2, 0.2]},
        rig={"cam0": SMALL0, "cam1": {**SMALL1, "noise_std": 0.01}},
        obstructed={"camera": "cam1", "effects": {"raindrops": {"count": 10}, "dirt": {}}},
    )
    first = _tree_digest(_render(tmp_path, data, "a"))
    second = _tree_digest(_render(tmp_path, data, "b"))
    assert first == second and len(first) > 10
    third = _tree_digest(_render(tmp_path, {**data, "seed": 4}, "c"))
    assert third != first
    assert third["camchain.yaml"] == first["camchain.yaml"]


def test_rotated_cam1_sees_the_scene_upside_down(tmp_path: Path) -> None:
    # Identical centred pinhole cameras and a wall so far that parallax is ~0:
    # then cam1's image is cam0's rotated by 180 degrees.
    pinhole = {"intrinsics": [300.0, 300.0, 159.5, 119.5], "distortion_model": "radtan",
               "resolution": [320, 240]}  # fmt: skip
    rig = {"baseline_m": 0.12, "cam1_rotated_180": True, "cam0": pinhole, "cam1": pinhole}
    wall = {**WALL, "depth_m": 5000.0, "tile_m": [4000.0, 4000.0]}
    data = _scene(tmp_path, rig=rig, planes=[wall], motion={"velocity_mps": [0, 0, 0]})
    data["rig"].pop("cam1_rotation_deg")
    out = _render(tmp_path, data)
    T = read_kalibr(out / "camchain.yaml").T_cam1_cam0
    np.testing.assert_allclose(T[:3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-12)
    frame = _geometry(out)["frames"][0]
    cam0 = read_image(out / "mav0" / "cam0" / "data" / f"{frame['cam0']['t_ns']}.png")
    cam1 = read_image(out / "mav0" / "cam1" / "data" / f"{frame['cam1']['t_ns']}.png")
    flipped = np.abs(cam1[::-1, ::-1].astype(int) - cam0).mean()
    upright = np.abs(cam1.astype(int) - cam0).mean()
    assert flipped < 1.0 < 10.0 < upright


def _undistort(image: np.ndarray, camera: CameraModel) -> np.ndarray:
    map_x, map_y = undistort_maps(camera)
    return np.asarray(cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR).astype(np.float32))


@pytest.mark.parametrize("obstructed", ["cam1", "cam0"])
def test_true_homography_registers_the_far_plane(tmp_path: Path, obstructed: str) -> None:
    data = _scene(tmp_path, recording={"frames": 2}, obstructed={"camera": obstructed})
    out = _render(tmp_path, data)
    rig = read_kalibr(out / "camchain.yaml")
    geometry = _geometry(out)
    clean = "cam0" if obstructed == "cam1" else "cam1"
    assert geometry["clean"] == clean and geometry["obstructed"] == obstructed
    assert geometry["far_plane"]["depth_m"] == 60.0
    for frame in geometry["frames"]:
        H = np.array(frame["homography"])
        # Translation parallel to the wall: only the wobble moves cam1 (0.11 m off the
        # body origin) by B sin(yaw) along the view direction, well under a millimetre.
        assert frame["far_plane_clean"]["distance_m"] == pytest.approx(60.0, abs=1e-3)
        images = {}
        for name in ("cam0", "cam1"):
            raw = read_image(out / "mav0" / name / "data" / f"{frame[name]['t_ns']}.png")
            images[name] = _undistort(raw, rig.camera(name))
        warped = cv2.warpPerspective(images[clean], H, (720, 540), flags=cv2.INTER_LINEAR)
        identity = images[clean]
        target = images[obstructed]
        centre = (slice(170, 370), slice(210, 510))
        registered = np.abs(warped[centre] - target[centre]).mean()
        unregistered = np.abs(identity[centre] - target[centre]).mean()
        assert registered < 2.5 and unregistered > 4 * registered
    np.testing.assert_allclose(geometry["homography"], geometry["frames"][0]["homography"])


def test_output_folder_must_be_new_or_empty(tmp_path: Path) -> None:
    (tmp_path / "rec").mkdir()
    (tmp_path / "rec" / "other.txt").write_text("x")
    spec_file = tmp_path / "s.yaml"
    spec_file.write_text(yaml.safe_dump(_scene(tmp_path)))
    with pytest.raises(SimulateError, match=r"rec: output folder is not empty"):
        simulate_recording(load_scene(spec_file), tmp_path / "rec")


def test_a_killed_simulation_starts_over_on_rerun_and_gives_the_same_bytes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from lenspair.simulate import recording

    data = _scene(tmp_path, recording={"frames": 4})
    whole = _tree_digest(_render(tmp_path, data, "whole"))
    assert ".simulate-incomplete" not in whole  # gone once complete
    writes = []
    real_write = recording.write_image

    def dies(path: Path, image: Any) -> None:
        writes.append(path)
        if len(writes) == 5:
            raise KeyboardInterrupt  # stands in for a kill mid-run
        real_write(path, image)

    monkeypatch.setattr(recording, "write_image", dies)
    with pytest.raises(KeyboardInterrupt):
        _render(tmp_path, data, "again")
    monkeypatch.setattr(recording, "write_image", real_write)
    assert (tmp_path / "again" / ".simulate-incomplete").is_file()
    assert _tree_digest(_render(tmp_path, data, "again")) == whole  # rerun: the same files


def test_a_simulation_still_running_is_not_taken_for_a_killed_one(tmp_path: Path) -> None:
    """A second simulate into the folder of a running one deleted its files under it."""
    import subprocess
    import sys

    from tests.processes import dead_pid

    data = _scene(tmp_path, recording={"frames": 2})
    out = tmp_path / "rec"
    out.mkdir()
    (out / "mav0").mkdir()
    running = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / ".simulate-incomplete").write_text(f"pid {running.pid}: removed when ...\n")
        with pytest.raises(SimulateError, match=rf"another simulate \(process {running.pid}\)"):
            _render(tmp_path, data, "rec")
        assert (out / "mav0").is_dir()  # its files left alone
    finally:
        running.kill()
        running.wait()
    (out / ".simulate-incomplete").write_text(f"pid {dead_pid()}: removed when ...\n")
    assert not (_render(tmp_path, data, "rec") / ".simulate-incomplete").exists()  # killed: redone


def test_the_written_scene_renders_again_from_the_recording(tmp_path: Path) -> None:
    """A texture file relative to the spec's folder is written by absolute path."""
    specs = tmp_path / "specs"
    write_image(
        specs / "tex.png", (np.random.default_rng(3).random((32, 32)) * 255).astype(np.uint8)
    )
    data = _scene(tmp_path, recording={"frames": 2})
    data["planes"] = [{"texture": "tex.png", "depth_m": 8.0}]
    (specs / "s.yaml").write_text(yaml.safe_dump(data))
    first = tmp_path / "first"
    simulate_recording(load_scene(specs / "s.yaml"), first, base_dir=specs)
    again = tmp_path / "again"
    simulate_recording(load_scene(first / "scene.yaml"), again, base_dir=first)
    assert _tree_digest(again)["mav0/cam0/data.csv"] == _tree_digest(first)["mav0/cam0/data.csv"]
    frames = sorted((first / "mav0" / "cam0" / "data").glob("*.png"))
    assert (
        frames[0].read_bytes() == (again / "mav0" / "cam0" / "data" / frames[0].name).read_bytes()
    )
    # the truth names the same file both times (it said "tex.png", then its absolute path)
    geometry = [json.loads((r / "truth" / "geometry.json").read_text()) for r in (first, again)]
    assert geometry[0]["planes"] == geometry[1]["planes"]
    assert geometry[0]["planes"][0]["texture"] == [str((specs / "tex.png").resolve())]


def test_scene_yaml_lists_only_the_declared_effects(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    out = tmp_path / "rain"
    assert main(["simulate", str(SAMPLES / "rain.yaml"), "--out", str(out), "--frames", "1"]) == 0
    written = yaml.safe_load((out / "scene.yaml").read_text())["obstructed"]["effects"]
    spec = load_scene(SAMPLES / "rain.yaml").obstructed.effects
    assert set(written) == set(spec.listed) and None not in written.values()
    with caplog.at_level("WARNING"):
        again = load_scene(out / "scene.yaml").obstructed.effects
    assert again.listed == spec.listed and not caplog.records  # nothing said of unlisted ones


def test_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "clean"
    args = ["simulate", str(SAMPLES / "clean.yaml"), "--out", str(out), "--frames", "2"]
    assert main([*args, "--seed", "9"]) == 0
    scene = load_scene(out / "scene.yaml")
    assert scene.recording.frames == 2 and scene.seed == 9
    assert len(_csv(out, "cam0")) == 2
    capsys.readouterr()
    assert main(args) == 2
    error = capsys.readouterr().err.strip()
    assert "output folder is not empty" in error and "\n" not in error
    bad = tmp_path / "bad.yaml"
    bad.write_text("rig: {baseline_m: 0.11}\nplanes: [{texture: bricks, depth_m: 40}]\n")
    assert main(["simulate", str(bad), "--out", str(tmp_path / "x")]) == 2
    error = capsys.readouterr().err.strip()
    assert "planes[0].texture: unknown texture 'bricks'" in error and "\n" not in error


def test_user_texture_file_comes_back_exactly(tmp_path: Path) -> None:
    # A flat sRGB texture survives decode -> linear render -> encode without a code change.
    from lenspair.core.imagewrite import write_image

    write_image(tmp_path / "flat.png", np.full((64, 64), 200, np.uint8))
    wall = {"texture": "flat.png", "depth_m": 40.0}
    out = _render(tmp_path, _scene(tmp_path, planes=[wall], rig=SMALL))
    image = read_image(out / "mav0" / "cam0" / "data" / f"{_csv(out, 'cam0')[0]}.png")
    assert np.all(image == 200)


def test_a_camera_whose_every_frame_is_dropped_is_refused_before_anything_is_written(
    tmp_path: Path,
) -> None:
    """It was written as a recording without obstructed frames, 'effects changed no pixel'."""
    spec = load_scene(SAMPLES / "rain.yaml")
    spec = replace(spec, recording=replace(spec.recording, frames=2, drop_probability=(0.0, 0.999)))
    with pytest.raises(SimulateError, match=r"drops every one of the 2 frame\(s\) of cam1"):
        simulate_recording(spec, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


def test_sensor_noise_is_added_behind_the_glass_not_blurred_by_it(tmp_path: Path) -> None:
    # The noise was drawn before the glass: inside defocused drops its fine-scale spread
    # fell from 7.4 to 0.8 codes, a cue no real camera gives a network.
    import cv2

    pinhole = {"intrinsics": [150.0, 150.0, 159.5, 119.5], "resolution": [320, 240]}
    drops = {"count": 6, "radius_px": [30, 40], "contact_angle_deg": [10, 15]}
    data = _scene(
        tmp_path,
        rig={"baseline_m": 0.11, "cam0": pinhole, "cam1": {**pinhole, "noise_std": 0.03}},
        planes=[{"texture": "page", "depth_m": 30.0}],
        motion={},
        recording={"frames": 1},
        obstructed={"camera": "cam1", "effects": {"raindrops": drops, "defocus": {}}},
    )
    out = _render(tmp_path, data)
    (name,) = [p.name for p in (out / "truth" / "mask").iterdir()]
    image = read_image(out / "mav0" / "cam1" / "data" / name).astype(np.float64)
    clear = read_image(out / "truth" / "clear" / name)
    mask = read_image(out / "truth" / "mask" / name) > 0
    fine = image - cv2.GaussianBlur(image, (0, 0), 1.0)
    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    outer = cv2.dilate(mask.astype(np.uint8), np.ones((5, 5), np.uint8)) == 0
    assert inner.sum() > 2000 and outer.sum() > 2000
    assert fine[inner].std() > 0.7 * fine[outer].std()
    assert np.array_equal(image[~mask], clear[~mask])  # the clear view's own draw outside


@pytest.mark.parametrize("along_m", [1.0e5, 3.0e5])
def test_a_camera_far_along_an_endless_plane_still_sees_its_texture(
    tmp_path: Path, along_m: float
) -> None:
    # within the spec's bounds the float32 plane coordinates lost the texture to rounding:
    # column-banded garbage, exit 0
    import cv2

    camera = {"resolution": [256, 192], "intrinsics": [240.0, 240.0, 127.5, 95.5]}

    def detail(start: float) -> float:
        data = _scene(
            tmp_path,
            rig={"baseline_m": 0.1, "cam0": camera},
            planes=[{"texture": "astronaut", "depth_m": 0.2}],
            motion={"start_m": [start, 0.0, 0.0]},
            recording={"frames": 1},
        )
        del data["rig"]["cam1"], data["rig"]["cam1_rotation_deg"]
        out = _render(tmp_path, data, f"at{int(start)}")
        (frame,) = (out / "mav0" / "cam0" / "data").iterdir()
        return float(np.abs(cv2.Laplacian(read_image(frame).astype(np.float64), -1)).mean())

    near, far = detail(0.0), detail(along_m)
    assert abs(far - near) < 0.1 * near


TINY = {
    "cam0": {"intrinsics": [60.0, 60.0, 31.5, 23.5], "resolution": [64, 48]},
    "cam1": {"intrinsics": [60.0, 60.0, 31.5, 23.5], "resolution": [64, 48]},
}


@pytest.mark.parametrize(
    ("planes", "motion", "frames", "refused"),
    [
        # driving 1 m/s into a wall 2 m ahead: at frame 40 (20 Hz) the rig reaches it
        ([{"texture": "brick", "depth_m": 2.0}], {"velocity_mps": [0, 0, 1.0]}, 60, 0),
        # a wall edge-on through the rig: every camera stands in it
        ([WALL, {"texture": "brick", "depth_m": 5.0, "rotation_deg": [90, 0, 0]}], None, 2, 1),
        # the same 40 frames stop short of it
        ([{"texture": "brick", "depth_m": 2.0}], {"velocity_mps": [0, 0, 1.0]}, 40, None),
        # a finite board beside the road is passed, not driven through
        ([WALL, {"texture": "brick", "depth_m": 0.5, "center_xy_m": [2.0, 0.0],
                 "size_m": [0.5, 0.5]}], {"velocity_mps": [0, 0, 1.0]}, 30, None),
    ],
    ids=["into-the-far-wall", "edge-on-wall", "stops-short", "passes-a-board"],
)  # fmt: skip
def test_a_rig_that_reaches_a_plane_it_cannot_pass_is_refused_before_writing(
    tmp_path: Path,
    planes: list[dict[str, Any]],
    motion: dict[str, Any] | None,
    frames: int,
    refused: int | None,
) -> None:
    # the far plane's homography divided by a distance of 0 or less: NaN in geometry.json
    data = _scene(tmp_path, rig={"baseline_m": 0.11, "cam0": TINY["cam0"], "cam1": TINY["cam1"]},
                  planes=planes, recording={"frames": frames})  # fmt: skip
    data["motion"] = motion or {"velocity_mps": [0.0, 0.0, 0.0]}
    if refused is None:
        out = _render(tmp_path, data)
        homographies = [f["homography"] for f in _geometry(out)["frames"]]
        assert np.isfinite(np.asarray(homographies, dtype=np.float64)).all()
        return
    with pytest.raises(SimulateError, match=rf"^planes\[{refused}\]: at frame \d+ a camera is"):
        _render(tmp_path, data)
    assert not (tmp_path / "rec").exists()  # nothing written


@pytest.mark.parametrize("meanwhile", ["another is writing", "another has finished"])
def test_a_folder_claimed_while_the_spec_was_set_up_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, meanwhile: str
) -> None:
    # two simulate runs started together both found the folder empty, then wrote their
    # frames into it: 16 images beside an 8-row data.csv, and no marker left to say so
    import subprocess
    import sys

    from lenspair.simulate import recording

    out = tmp_path / "rec"
    setup = recording._setup
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])

    def racing(spec: Any, base_dir: Path) -> Any:
        out.mkdir()
        if meanwhile == "another is writing":
            (out / recording.INCOMPLETE).write_text(f"pid {other.pid}: removed when ...\n")
        else:
            (out / "rig.yaml").write_text("another recording\n")
        return setup(spec, base_dir)

    monkeypatch.setattr(recording, "_setup", racing)
    spec_file = tmp_path / "rec.yaml"
    spec_file.write_text(yaml.safe_dump(_scene(tmp_path, rig=SMALL)))
    try:
        expected = (
            rf"another simulate \(process {other.pid}\) is writing it"
            if meanwhile == "another is writing"
            else "another simulate filled it meanwhile"
        )
        with pytest.raises(SimulateError, match=expected):
            simulate_recording(load_scene(spec_file), out, base_dir=tmp_path)
    finally:
        other.kill()
        other.wait()
    assert not (out / "mav0").exists()  # nothing of this run was written


def test_a_marker_made_this_instant_is_not_taken_for_a_killed_run(tmp_path: Path) -> None:
    # a run that read another's marker between its creation and its pid took it for a
    # killed run's, emptied the folder and claimed it too
    from lenspair.simulate import recording

    out = tmp_path / "rec"
    out.mkdir()
    (out / recording.INCOMPLETE).touch()
    (out / "frame.png").write_bytes(b"the other run's")
    spec_file = tmp_path / "rec.yaml"
    spec_file.write_text(yaml.safe_dump(_scene(tmp_path, rig=SMALL)))
    with pytest.raises(SimulateError, match="another simulate is claiming it this instant"):
        simulate_recording(load_scene(spec_file), out, base_dir=tmp_path)
    assert sorted(p.name for p in out.iterdir()) == sorted([recording.INCOMPLETE, "frame.png"])
