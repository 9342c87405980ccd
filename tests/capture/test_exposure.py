"""How alike the two cameras expose: each pair's ratio, the recording's summary and warnings."""

import logging
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.capture.exposure import exposure_summary, exposure_warnings
from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingested import ExposureSummary, PairRecord, read_report
from lenspair.core.imageio import read_image
from lenspair.core.imagewrite import write_image
from lenspair.core.quality import exposure_ratio
from tests.capture.ingest_helpers import frame_files, make_recording


@given(gain=st.floats(0.3, 3.0))
def test_a_gain_between_the_views_is_the_ratio(gain: float) -> None:
    rng = np.random.default_rng(0)
    grey = rng.uniform(0.06, 0.3, (40, 60)).astype(np.float32)
    ratio = exposure_ratio(grey, grey * np.float32(gain))
    assert ratio == pytest.approx(gain, rel=1e-5)


def test_untrusted_clipped_and_black_pixels_do_not_count() -> None:
    grey = np.full((40, 60), 0.4, np.float32)
    target = grey * np.float32(0.8)
    untrusted = np.zeros(grey.shape, bool)
    target[:, :25] = 0.9  # parallax the mask marks: a ratio of 2.25 there
    untrusted[:, :25] = True
    target[:3] = 1.0  # clipped: would read 2.5
    assert exposure_ratio(grey, target, untrusted) == pytest.approx(0.8)
    black = np.full((40, 60), 0.02, np.float32)  # a night frame: nothing to judge by
    assert exposure_ratio(black, black * 2) is None


def _kept(ratios: list[float | None]) -> list[PairRecord]:
    return [PairRecord(t_ns=i, status="kept", exposure_ratio=r) for i, r in enumerate(ratios)]


def test_the_summary_and_what_it_warns_of() -> None:
    alike = exposure_summary([*_kept([0.98, 1.0, 1.02, None]), PairRecord(9, "rejected")])
    assert alike == ExposureSummary(median=1.0, low=0.984, high=1.016, pairs=3)
    assert exposure_warnings(alike) == []
    # drops over a scene (the ours preset's 0.90-0.96) are no exposure problem
    assert exposure_warnings(exposure_summary(_kept([0.9, 0.93, 0.96]))) == []
    (darker,) = exposure_warnings(exposure_summary(_kept([0.6, 0.62, 0.61])))
    assert "frames are darker" in darker and "median target/input grey ratio 0.61" in darker
    (changing,) = exposure_warnings(exposure_summary(_kept([0.8, 1.0, 1.3, 0.85, 1.25])))
    assert "changes from pair to pair" in changing and "auto-exposure" in changing
    assert exposure_summary(_kept([None])) is None and exposure_warnings(None) == []


@pytest.mark.parametrize("gain", [1.0, 0.6])
def test_ingest_records_the_cameras_exposure_and_warns_of_a_darker_clean_camera(
    tmp_path: Path, gain: float, caplog: pytest.LogCaptureFixture
) -> None:
    # a clean camera set darker went into every target without a word: photometric_residual
    # is measured after a local gain fit, and every pair was kept
    recording = make_recording(tmp_path / "rec", frames=3)  # cam0, clean, at 0.85 already
    for path in frame_files(recording, "cam0"):
        write_image(path, np.rint(read_image(path) * gain).astype(np.uint8))
    with caplog.at_level(logging.WARNING):
        report = ingest_recording(recording, tmp_path / "out", size=(240, 160))
    assert report.exposure is not None and report.exposure.pairs == report.counts["kept"] == 3
    # 8-bit codes scaled by the gain: the ratio of grey levels as stored
    assert report.exposure.median == pytest.approx(0.85 * gain, abs=0.03)
    warned = any("frames are darker than the obstructed" in m for m in caplog.messages)
    assert warned == (gain < 1)
    assert read_report(tmp_path / "out" / report.recording_id / "report.json") == report
