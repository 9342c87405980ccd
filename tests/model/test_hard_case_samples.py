"""Hard-case training samples (issue #14): labels, maps, sizes, determinism, parallel gathering."""

from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest

from lenspair.capture.recording import FrameRef
from lenspair.model.detection import hard_cases
from lenspair.model.detection.data import visible_footprint
from lenspair.model.detection.hard_cases import (
    HARD_CASES,
    HARD_KINDS,
    clean_views,
    hard_sample,
    hard_samples,
    light_rain,
    load_view,
    veiled_dust,
)
from lenspair.model.detection.labels import pair_anomaly_mask
from lenspair.model.detection.simset import SCENE_KINDS
from lenspair.model.detection.sources import DetectorSources, gather
from lenspair.model.errors import ModelError
from lenspair.model.networks.detector import KINDS, DetectorSpec
from tests.capture.ingest_helpers import simulate
from tests.images import texture

SPEC = DetectorSpec()


@pytest.fixture(scope="module")
def rain(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sample light rain (obstructed cam1), 2 frames."""
    return simulate("rain", tmp_path_factory.mktemp("hard") / "rain", frames=2)


@pytest.fixture(scope="module")
def view(rain: Path) -> np.ndarray:
    return load_view(clean_views(rain)[0])


def test_visible_footprint_counts_an_even_darkening() -> None:
    clear = (40 + 180 * texture((120, 160), seed=1)).astype(np.uint8)
    darker = np.round(clear * 0.6).astype(np.uint8)
    everywhere = np.ones(clear.shape, np.uint8)
    assert visible_footprint(darker, clear, everywhere).mean() > 0.95
    # With gain compensation (two cameras) the same darkening is an exposure change.
    assert pair_anomaly_mask(darker, clear, threshold=0.05).mean() < 0.05


def test_clean_views_are_the_clean_camera_and_truth_clear(rain: Path) -> None:
    views = clean_views(rain)
    frames = [v for v in views if isinstance(v, FrameRef)]
    files = [v for v in views if isinstance(v, Path)]
    assert len(frames) == len(files) == 2
    assert {f.camera for f in frames} == {"cam0"}  # cam1 is behind the rain
    assert all(f.parent == rain / "truth" / "clear" for f in files)
    image = load_view(files[0])
    assert image.dtype == np.uint8 and image.shape == (540, 720)


def test_cases_cycle_with_their_labels(rain: Path) -> None:
    samples = hard_samples(clean_views(rain), 10, SPEC, np.random.default_rng(0), first=3)
    for number, sample in enumerate(samples, start=3):
        case = HARD_CASES[number % len(HARD_CASES)]
        assert sample.source == f"hard:{case}:{number}"
        assert sample.image.shape == SPEC.input_size and sample.tiles.shape == SPEC.grid
        assert sample.kind == KINDS.index(HARD_KINDS[case])  # effects here are visible
        assert sample.tiles.any() == (sample.kind != 0)


@pytest.mark.parametrize("seed", range(4))
def test_negatives_are_clean_with_empty_maps(view: np.ndarray, seed: int) -> None:
    rng = np.random.default_rng(seed)
    for case in ("defocus", "exposure", "flat"):
        sample = hard_sample(view, case, SPEC, rng, case, "g")
        assert sample.kind == 0 and not sample.tiles.any() and sample.valid.all()


@pytest.mark.parametrize("seed", range(4))
def test_veiled_dust_covers_most_of_the_frame(view: np.ndarray, seed: int) -> None:
    sample = hard_sample(view, "veiled_dust", SPEC, np.random.default_rng(seed), "d", "g")
    assert sample.kind == KINDS.index("dust")
    assert sample.tiles.mean() > 0.25


@pytest.mark.parametrize("seed", range(4))
def test_light_rain_covers_part_of_the_frame(view: np.ndarray, seed: int) -> None:
    sample = hard_sample(view, "light_rain", SPEC, np.random.default_rng(seed), "r", "g")
    assert sample.kind == KINDS.index("rain")
    assert 0.0 < sample.tiles.mean() < 0.7


def test_an_invisible_positive_is_clean(view: np.ndarray, monkeypatch: pytest.MonkeyPatch) -> None:
    def no_change(image: np.ndarray, effects: object, rng: object) -> tuple[np.ndarray, np.ndarray]:
        return image.copy(), np.ones(image.shape, np.uint8)

    monkeypatch.setattr(hard_cases, "render_effects", no_change)
    sample = hard_sample(view, "veiled_dust", SPEC, np.random.default_rng(0), "d", "g")
    assert sample.kind == 0 and not sample.tiles.any()


def test_effect_sizes_follow_the_frame_width() -> None:
    sample_rain = SCENE_KINDS["rain"]
    assert sample_rain.raindrops is not None
    full = light_rain(720, np.random.default_rng(0))
    half = light_rain(360, np.random.default_rng(0))
    assert full.raindrops is not None and half.raindrops is not None
    assert full.raindrops.radius_px == sample_rain.raindrops.radius_px
    assert half.raindrops.radius_px == (3.0, 11.0)
    assert half.defocus is not None and half.defocus.shift_px == pytest.approx(1.5)
    dust = veiled_dust(720, np.random.default_rng(0)).dust
    assert dust is not None and 144 <= dust.scale_px <= 240 and dust.coverage >= 0.8


def test_same_seed_same_samples(rain: Path) -> None:
    views = clean_views(rain)
    first, again = (hard_samples(views, 5, SPEC, np.random.default_rng(7)) for _ in range(2))
    for one, two in zip(first, again, strict=True):
        np.testing.assert_array_equal(one.image, two.image)
        np.testing.assert_array_equal(one.tiles, two.tiles)


def test_hard_cases_need_views() -> None:
    with pytest.raises(ValueError, match="at least one clean view"):
        hard_samples([], 1, SPEC, np.random.default_rng(0))


@pytest.mark.slow
def test_gathered_samples_do_not_depend_on_workers(rain: Path) -> None:
    sources = DetectorSources(recordings=(rain,), synthetic=70, hard=65, max_frames=2)
    single, _ = gather(sources, SPEC, seed=3, workers=1)
    pooled, _ = gather(sources, SPEC, seed=3, workers=2)
    assert len(single) == len(pooled) == 4 + 70 + 65
    for one, two in zip(single, pooled, strict=True):
        assert asdict(one).keys() == asdict(two).keys()
        assert (one.source, one.kind, one.group) == (two.source, two.kind, two.group)
        np.testing.assert_array_equal(one.image, two.image)
        np.testing.assert_array_equal(one.tiles, two.tiles)


def test_a_recording_trained_on_is_not_scored_and_a_repeat_is_read_once(
    rain: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Scored on the frames it trained on, without a word; given twice, trained on twice."""
    typed_otherwise = rain.parent / "." / rain.name
    with pytest.raises(ModelError, match=r"--test-recordings: .* is also in --recordings"):
        gather(DetectorSources(recordings=(rain,), test_recordings=(typed_otherwise,)), SPEC, 0)
    once, _ = gather(DetectorSources(recordings=(rain,), max_frames=2), SPEC, 0)
    with caplog.at_level("WARNING"):
        twice, _ = gather(
            DetectorSources(recordings=(rain, typed_otherwise), max_frames=2), SPEC, 0
        )
    assert len(twice) == len(once)
    assert any("given twice in --recordings" in m for m in caplog.messages)


@pytest.mark.parametrize(
    ("given", "held", "message"),
    [  # the set's last recording of each kind is held out, the others trained on
        ("recordings", "rain_1", r"held-out recordings: \S*rain_1 is also in --recordings"),
        ("test_recordings", "rain_0", r"--test-recordings: \S*rain_0 is also in --simulated-set"),
    ],
)
def test_a_simulated_set_recording_is_not_both_trained_on_and_scored(
    tmp_path: Path, given: str, held: str, message: str
) -> None:
    """Its held-out scores came from frames it trained on; refused before anything renders."""
    sims = tmp_path / "sims"
    sources = DetectorSources(simulated_set=sims, set_per_kind=2, set_frames=1)
    with pytest.raises(ModelError, match=message):
        gather(replace(sources, **{given: (sims / held,)}), SPEC, 0)
    assert not sims.exists()


@pytest.mark.parametrize(("clean", "said"), [("", "is"), ("mav0", "lies in"), ("..", "holds")])
def test_clean_images_from_a_scored_recording_are_refused(
    tmp_path: Path, clean: str, said: str
) -> None:
    """Synthetic frames cut from the recording then scored flattered its scores, unsaid."""
    scored = tmp_path / "rec_clean"
    (scored / "mav0").mkdir(parents=True)
    folder = scored / clean
    sources = DetectorSources(synthetic=2, clean_folder=folder, test_recordings=(scored,))
    with pytest.raises(ModelError, match=rf"^--clean-images {folder}: {said} the --test-rec"):
        gather(sources, SPEC, 0)
