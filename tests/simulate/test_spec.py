from pathlib import Path

import pytest
import yaml

from lenspair.core.config import MAX_SEED, dump_yaml, load_yaml
from lenspair.core.errors import ConfigError
from lenspair.simulate.spec import SceneSpec, load_scene, with_overrides
from lenspair.simulate.stereo import rig_from_spec

SAMPLES = Path(__file__).resolve().parents[2] / "calib_samples"
SCENES = sorted(p for p in SAMPLES.glob("*.yaml") if p.name != "alphasense_camchain.yaml")

MINIMAL = {
    "rig": {"baseline_m": 0.12},
    "planes": [{"texture": "brick", "depth_m": 40.0}],
}


def _write(tmp_path: Path, data: dict) -> Path:
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _with(path: str, value: object) -> dict:
    """MINIMAL with one dotted key set (list indices as [i])."""
    data = yaml.safe_load(yaml.safe_dump(MINIMAL))
    node = data
    parts = path.replace("[", ".").replace("]", "").split(".")
    for part in parts[:-1]:
        node = node[int(part)] if part.isdigit() else node.setdefault(part, {})
    node[parts[-1]] = value
    return data


def test_samples_exist_and_load() -> None:
    names = {p.stem for p in SCENES}
    assert {
        "rain",
        "dust_swapped",
        "parallax",
        "clean",
        "chessboard",
        "charuco",
        "rotated",
    } <= names
    for path in SCENES:
        spec = load_scene(path)
        assert 0.11 <= spec.rig.baseline_m <= 0.14
        assert spec.recording.frames <= 20


def test_sample_obstruction_and_rotation() -> None:
    rain = load_scene(SAMPLES / "rain.yaml")
    assert rain.obstructed.camera == "cam1"
    assert rain.obstructed.effects.listed == ("raindrops", "brightness", "defocus")
    assert not rain.rig.cam1_rotated_180
    dust = load_scene(SAMPLES / "dust_swapped.yaml")
    assert dust.obstructed.camera == "cam0" and dust.obstructed.effects.anomaly_kinds == ("dust",)
    assert load_scene(SAMPLES / "rotated.yaml").rig.cam1_rotated_180
    assert load_scene(SAMPLES / "clean.yaml").obstructed.effects.listed == ()
    parallax = load_scene(SAMPLES / "parallax.yaml")
    assert min(p.depth_m for p in parallax.planes) <= 3.0
    for name in ("rain", "dust_swapped", "clean", "rotated"):
        spec = load_scene(SAMPLES / f"{name}.yaml")
        assert min(p.depth_m for p in spec.planes) >= 40.0


def test_minimal_spec_defaults(tmp_path: Path) -> None:
    spec = load_scene(_write(tmp_path, MINIMAL))
    assert spec.rig.cam0.resolution == (720, 540)
    assert spec.rig.baseline_m == 0.12
    assert spec.obstructed.camera == "cam1"
    assert spec.far_plane_index == 0
    assert spec.board is None


def test_round_trip_through_dump(tmp_path: Path) -> None:
    for path in SCENES:
        spec = load_scene(path)
        again = tmp_path / f"{path.stem}.yaml"
        again.write_text(dump_yaml(spec))
        assert load_yaml(SceneSpec, again) == spec


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"planes": MINIMAL["planes"]}, r"rig: required key is missing"),
        ({"rig": {}, "planes": MINIMAL["planes"]}, r"rig\.baseline_m: required key is missing"),
        (_with("rig.baseline_m", "wide"), r"rig\.baseline_m: expected float, got 'wide'"),
        (_with("rig.baseline_m", 5.0), r"rig\.baseline_m: expected 0 < baseline <= 2 m"),
        (_with("rig.cam0.distortion_model", "fisheye"), r"rig\.cam0\.distortion_model: expected"),
        (_with("rig.cam1.intrinsics", [350.0, 350.0]), r"rig\.cam1\.intrinsics: expected 4 values"),
        (_with("rig.bit_depth", 12), r"rig\.bit_depth: expected 8 or 16"),
        (_with("planes[0].depht_m", 3.0), r"planes\[0\]\.depht_m: unknown key"),
        (_with("planes[0].depth_m", "far"), r"planes\[0\]\.depth_m: expected float"),
        (_with("planes[0].texture", "bricks"), r"planes\[0\]\.texture: unknown texture 'bricks'"),
        (  # a file name: where it was looked for, not "unknown texture"
            _with("planes[0].texture", "walls/nofile.png"),
            r"planes\[0\]\.texture: .*walls/nofile\.png: no such file \(a texture file is read "
            r"relative to the scene spec's folder\)",
        ),
        (_with("recording.jitter_us", 20000.0), r"recording\.jitter_us: expected 0 <= 3 sigma"),
        # a jitter so large that start_ns could not hold 3 sigma of it: jitter_us is at fault
        (_with("recording.jitter_us", 1e15), r"recording\.jitter_us: expected 0 <= 3 sigma"),
        (_with("recording.drop_probability", [0.0, 1.0]), r"recording\.drop_probability"),
        (_with("obstructed.camera", "cam2"), r"obstructed\.camera: expected one of 'cam0', 'cam1'"),
        (
            _with("obstructed.effects", {"raindrops": {"cont": 3}}),
            r"obstructed\.effects\.raindrops\.cont: unknown key",
        ),
        (
            _with("board", {"kind": "chessboard", "cols": 9, "rows": 6}),
            r"board\.square_m: required key is missing",
        ),
        (
            _with(
                "board",
                {
                    "kind": "charuco",
                    "cols": 5,
                    "rows": 4,
                    "square_m": 0.1,
                    "dictionary": "DICT_9X9",
                },
            ),
            r"board\.dictionary: unknown 'DICT_9X9'",
        ),
        ({"rig": {"baseline_m": 0.11}}, r"planes: a scene needs at least one plane or a board"),
        # values in range of their type, but no camera or motion gives them: each rendered
        # blank frames, NaN poses or an overflow, exit 0, and still labelled an anomaly
        (_with("motion.frequency_hz", 1.0e308), r"motion\.frequency_hz: expected 0\.\.100 Hz"),
        (
            _with("rig.cam0.intrinsics", [350.0, 350.0, -1.0e6, 269.5]),
            r"rig\.cam0\.intrinsics: principal point \(-1000000\.0, 269\.5\) lies more",
        ),
        (_with("rig.cam0.intrinsics", [1e-300, 350.0, 359.5, 269.5]), r"focal lengths expected"),
        (_with("rig.cam0.distortion", [1e300, 0, 0, 0]), r"rig\.cam0\.distortion: expected"),
        (_with("rig.cam0.gain", 1e300), r"rig\.cam0\.gain: expected 0 < gain <= 100"),
        (_with("planes[0].brightness", 1e300), r"planes\[0\]\.brightness: expected 0 <"),
        (
            _with(
                "board",
                {
                    "kind": "chessboard",
                    "cols": 64,
                    "rows": 64,
                    "square_m": 0.05,
                    "pixels_per_square": 512,
                },
            ),
            r"board\.pixels_per_square: a 64x64 board at 512 px a square is a texture of 1177 M",
        ),
        (
            _with("board", {"kind": "chessboard", "cols": 9, "rows": 6, "square_m": 1.0}),
            r"board\.square_m: expected 0\.002 <= square_m < 1 m",  # --board refuses 1 m
        ),
    ],
)
def test_errors_name_the_key(tmp_path: Path, data: dict, message: str) -> None:
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError, match=message) as info:
        load_scene(path)
    text = str(info.value)
    assert text.startswith(str(path)) and "\n" not in text


def test_texture_path_relative_to_spec(tmp_path: Path) -> None:
    import numpy as np

    from lenspair.core.imagewrite import write_image

    write_image(tmp_path / "wall.png", np.full((64, 64), 128, np.uint8))
    spec = load_scene(_write(tmp_path, _with("planes[0].texture", "wall.png")))
    assert spec.planes[0].textures == ("wall.png",)


def test_a_texture_file_that_is_no_image_is_refused_with_the_spec_and_key(
    tmp_path: Path,
) -> None:
    """It named neither, and came only once the simulation had made its folder."""
    import OpenImageIO as oiio

    from lenspair.cli import main

    (tmp_path / "notes.yaml").write_text("a: 1\n")
    spec = _write(tmp_path, _with("planes[0].texture", "notes.yaml"))
    with pytest.raises(ConfigError, match=r"planes\[0\]\.texture: .*notes\.yaml: cannot open"):
        load_scene(spec)
    float_tiff = oiio.ImageBuf(oiio.ImageSpec(16, 16, 1, "float"))
    assert float_tiff.write(str(tmp_path / "depth.tif"))
    with pytest.raises(ConfigError, match=r"depth\.tif: float pixels; a texture is an 8- or 16"):
        load_scene(_write(tmp_path, _with("planes[0].texture", "depth.tif")))
    assert main(["simulate", str(spec), "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


def test_overrides() -> None:
    spec = load_scene(SAMPLES / "clean.yaml")
    changed = with_overrides(spec, frames=3, seed=11)
    assert changed.recording.frames == 3 and changed.seed == 11
    assert with_overrides(spec) == spec
    # named as the option typed: the spec's key meant nothing to a user of --frames
    with pytest.raises(ConfigError, match=r"^--frames expected 1\.\.100000, got 0$"):
        with_overrides(spec, frames=0)
    for seed in (-1, MAX_SEED + 1):  # the range of every command's --seed
        with pytest.raises(ConfigError, match=rf"^--seed expected 0 \.\. {MAX_SEED}, got {seed}$"):
            with_overrides(spec, seed=seed)
    assert with_overrides(spec, seed=MAX_SEED).seed == MAX_SEED


@pytest.mark.parametrize(
    ("section", "value", "message"),
    [
        ("recording", {"start_ns": 2**63 - 10}, "start_ns: expected"),
        ("recording", {"start_ns": 0, "jitter_us": 1000.0}, "start_ns: expected"),
        ("planes", [{"texture": "brick", "depth_m": 5.0, "tile_m": [1e-38, 1e-38]}], "tile_m"),
        ("planes", [{"texture": "brick", "depth_m": 5.0, "size_m": [1e300, 1e300]}], "size_m"),
        ("planes", [{"texture": "brick", "depth_m": 5.0, "center_xy_m": [1e300, 0]}], "center"),
        # the rig far away or fast: float32 rendering turned every frame black, with exit 0
        ("motion", {"start_m": [1.0e38, 0, 0]}, r"motion\.start_m: expected"),
        ("motion", {"velocity_mps": [1.0e40, 0, 0]}, r"motion\.velocity_mps: expected"),
        (
            "rig",
            {"baseline_direction": [float("inf"), 0, 0]},
            r"baseline_direction\[0\]: expected a finite",
        ),
        ("obstructed", {"camera": "cam1", "effects": {"raindrops": {"count": 10**12}}}, "count"),
        # 200 drops of 300 px: gigabytes of drop pixels (a MemoryError traceback before)
        (
            "obstructed",
            {"camera": "cam1", "effects": {"raindrops": {"count": 200, "radius_px": [300, 300]}}},
            r"^\S*s.yaml: obstructed.effects.raindrops: 200 drops of radius up to 300 px cover "
            r"up to 6.53e\+07 pixels of a 720x540 frame",
        ),
        (
            "obstructed",
            {"camera": "cam1", "effects": {"dirt": {"count": 2000, "radius_px": [10, 100]}}},
            r"obstructed.effects.dirt: 2000 blobs .* use fewer or smaller blobs$",
        ),
    ],
)
def test_values_that_would_overflow_or_exhaust_memory_are_refused(
    tmp_path: Path, section: str, value: object, message: str
) -> None:
    data = yaml.safe_load((SAMPLES / "rain.yaml").read_text())
    data[section] = {**data[section], **value} if isinstance(value, dict) else value
    spec = tmp_path / "s.yaml"
    spec.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=message):
        load_scene(spec)


def test_a_huge_baseline_direction_keeps_the_baseline(tmp_path: Path) -> None:
    # its length overflowed to inf, and the baseline written to the truth files was 0
    data = yaml.safe_load((SAMPLES / "rain.yaml").read_text())
    data["rig"]["baseline_direction"] = [1.0e308, 1.0e308, 0.0]
    rig = rig_from_spec(load_scene(_write(tmp_path, data)).rig)
    assert rig.baseline_m == pytest.approx(data["rig"]["baseline_m"])


def test_a_frame_too_large_to_render_is_refused_at_the_spec(tmp_path: Path) -> None:
    # 8192x8192 at 4x4 samples: about 180 GB to render (a MemoryError traceback)
    data = yaml.safe_load((SAMPLES / "rain.yaml").read_text())
    for camera in ("cam0", "cam1"):
        data["rig"].setdefault(camera, {})["resolution"] = [8192, 8192]
    data["supersample"] = 4
    with pytest.raises(ConfigError, match=r"supersample: 4 at rig\.cam0\.resolution 8192x8192"):
        load_scene(_write(tmp_path, data))
    data["supersample"] = 1  # the largest frame, once: allowed
    assert load_scene(_write(tmp_path, data)).supersample == 1


def test_glass_optics_left_unset_follow_the_obstructed_camera(tmp_path: Path) -> None:
    # Drop refraction and the glass blur once assumed a 350 px camera whatever the scene's.
    data = _with("rig.cam1.intrinsics", [700.0, 700.0, 359.5, 269.5])
    data["obstructed"] = {"effects": {"raindrops": {"count": 5}, "defocus": {}}}
    effects = load_scene(_write(tmp_path, data)).obstructed.effects
    assert effects.raindrops is not None and effects.raindrops.focal_px == 700.0
    assert effects.defocus is not None and effects.defocus.focal_px == pytest.approx(700.0)
    # thin lens: f_px * (focal / f_number) / d = 700 * 1.2 mm / 30 mm
    assert effects.defocus.blur_diameter_px == pytest.approx(28.0)
    # what a scene sets stays, and scene.yaml (the dump) re-renders the same
    data["obstructed"]["effects"]["raindrops"]["focal_px"] = 400.0
    data["obstructed"]["effects"]["defocus"]["pixel_pitch_um"] = 3.0
    effects = load_scene(_write(tmp_path, data)).obstructed.effects
    assert effects.raindrops is not None and effects.raindrops.focal_px == 400.0
    assert effects.defocus is not None and effects.defocus.pixel_pitch_um == 3.0
    spec = load_scene(_write(tmp_path, data))
    assert load_yaml(SceneSpec, _dumped(tmp_path, spec)) == spec


def _dumped(tmp_path: Path, spec: SceneSpec) -> Path:
    path = tmp_path / "dumped.yaml"
    path.write_text(dump_yaml(spec))
    return path


def test_a_camera_that_makes_the_glass_blur_impossible_is_named(tmp_path: Path) -> None:
    data = _with("rig.cam1.intrinsics", [9000.0, 9000.0, 359.5, 269.5])
    data["obstructed"] = {"effects": {"defocus": {}}}
    with pytest.raises(ConfigError, match=r"obstructed\.effects\.defocus\.glass_distance_m: .*fx"):
        load_scene(_write(tmp_path, data))


def test_a_blur_is_judged_for_the_scenes_camera_not_the_photo_default(tmp_path: Path) -> None:
    # A 175 px camera behind glass 3 mm away blurs 70 px: refused as the 139 px of 350 px.
    data = _with("rig.cam1.intrinsics", [175.0, 175.0, 179.5, 134.5])
    data["rig"]["cam1"]["resolution"] = [360, 270]
    data["rig"]["cam0"] = {"resolution": [360, 270], "intrinsics": [175.0, 175.0, 179.5, 134.5]}
    data["obstructed"] = {"effects": {"defocus": {"glass_distance_m": 0.003}}}
    effects = load_scene(_write(tmp_path, data)).obstructed.effects
    assert effects.defocus is not None
    assert effects.defocus.blur_diameter_px == pytest.approx(70.0)


def test_a_bare_effect_key_is_off_and_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    data = _with("obstructed", {"camera": "cam1", "effects": {"dust": None, "veil": {}}})
    with caplog.at_level("WARNING", logger="lenspair.simulate.spec"):
        effects = load_scene(_write(tmp_path, data)).obstructed.effects
    assert effects.dust is None and effects.veil is not None  # null: off; {}: its defaults
    (said,) = [r.getMessage() for r in caplog.records]
    assert "obstructed.effects.dust is empty (null), which leaves dust off" in said
    assert "'dust: {}'" in said
