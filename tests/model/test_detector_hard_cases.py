"""The bundled detector (calib_samples/detector.pt) on the issue's hard cases.

Scenes come from the simulator's clean sample (calib_samples/clean.yaml):
new views and a new seed, but its textures are among those the detector was
trained on, so these check behaviour on known kinds of scene.
"""

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from lenspair.capture.recording import open_recording
from lenspair.core.samples import sample_path
from lenspair.model.detection import judge as judge_module
from lenspair.model.detection.judge import Judgement, judge, obstructed_probability
from lenspair.model.detection.train import load_detector
from lenspair.model.networks.detector import AnomalyDetector
from lenspair.simulate.effects.spec import DustSpec, EffectsSpec
from lenspair.simulate.render import render_effects
from tests.capture.ingest_helpers import simulate


@pytest.fixture(scope="module")
def detector() -> AnomalyDetector:
    return load_detector(sample_path("detector.pt"))


@pytest.fixture(scope="module")
def clean_frames(tmp_path_factory: pytest.TempPathFactory) -> list[np.ndarray]:
    folder = simulate("clean", tmp_path_factory.mktemp("sim") / "clean", frames=3)
    recording = open_recording(Path(folder))
    return [recording.load(frame) for frame in recording.frames["cam0"]]


def test_all_black_and_saturated_frames(detector: AnomalyDetector) -> None:
    frames = [np.zeros((360, 540), np.uint8), np.full((360, 540, 3), 255, np.uint8)]
    verdict = judge(detector, frames)
    assert verdict.blank.all()
    assert not verdict.obstructed.any()
    assert np.isfinite(verdict.probability).all() and np.isfinite(verdict.maps).all()


def _variants(clean_frames: list[np.ndarray], blur: bool) -> list[np.ndarray]:
    frames = []
    for frame in clean_frames:
        scene = frame.astype(np.float32)
        if blur:
            scene = cv2.GaussianBlur(scene, (0, 0), 4.0)
        for gain in (1.0, 0.25):
            frames.append(np.clip(scene * gain, 0, 255).astype(np.uint8))
    return frames


def test_clean_and_dark_frames_are_not_obstructed(
    detector: AnomalyDetector, clean_frames: list[np.ndarray]
) -> None:
    verdict = judge(detector, _variants(clean_frames, blur=False))
    assert not verdict.obstructed.any(), verdict.probability


def test_clean_blurry_frames_are_not_obstructed(
    detector: AnomalyDetector, clean_frames: list[np.ndarray]
) -> None:
    verdict = judge(detector, _variants(clean_frames, blur=True))
    assert not verdict.obstructed.any(), verdict.probability


def test_smooth_darkening_dust_is_detected(
    detector: AnomalyDetector, clean_frames: list[np.ndarray]
) -> None:
    dust = EffectsSpec(
        dust=DustSpec(attenuation=(0.5, 0.7), scatter=0.05, scale_px=150.0, coverage=1.0)
    )
    rng = np.random.default_rng(0)
    dusty = [render_effects(frame, dust, rng)[0] for frame in clean_frames]
    verdict = judge(detector, dusty)
    assert verdict.obstructed.all(), verdict.probability


def test_the_side_check_function_never_counts_a_blank_frame_as_obstructed(
    detector: AnomalyDetector, monkeypatch: pytest.MonkeyPatch
) -> None:
    black = np.zeros((90, 120), np.uint8)
    texture = np.random.default_rng(0).integers(0, 255, (90, 120), dtype=np.uint8)

    def certain(
        network: AnomalyDetector, images: list[np.ndarray], bits: int | None = None
    ) -> Judgement:
        # a detector that (wrongly) scores every frame obstructed, blank ones too
        verdict = judge(network, images, bits=bits)
        return replace(verdict, probability=np.ones_like(verdict.probability))

    monkeypatch.setattr(judge_module, "judge", certain)
    probabilities = obstructed_probability(detector)([black, texture])
    assert probabilities.tolist() == [0.0, 1.0]
