"""capture-ingest --detector on the sample light-rain recording, with the side swapped."""

from typing import Any

import pytest

from lenspair.capture.ingest import ingest_recording
from lenspair.capture.recording import load_frame, open_recording
from lenspair.capture.side_check import check_obstructed_side
from lenspair.core.samples import sample_path
from lenspair.model.detection.judge import obstructed_probability
from lenspair.model.detection.train import load_detector
from tests.capture.ingest_helpers import simulate


@pytest.fixture(scope="module")
def swapped(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Ingest the sample rain (on cam1) declared as cam0, side-checked by the bundled detector."""
    root = tmp_path_factory.mktemp("rain")
    recording = simulate("rain", root / "rain", frames=6)
    frames = open_recording(recording).frames
    images = {camera: [load_frame(frame) for frame in frames[camera]] for camera in frames}
    count = min(len(images["cam0"]), len(images["cam1"]))
    detail = check_obstructed_side(images["cam0"][:count], images["cam1"][:count], "cam1")
    detector = obstructed_probability(load_detector(sample_path("detector.pt")))
    report = ingest_recording(recording, root / "out", obstructed="cam0", side_detector=detector)
    return {"detail": detail, "side": report.side_check}


@pytest.mark.slow
def test_ingest_reports_the_detector_side_check(swapped: dict[str, Any]) -> None:
    # The detail-ratio check cannot decide on this light rain: the reason for the detector.
    assert swapped["detail"].inferred == "undetermined"
    side = swapped["side"]
    assert side["method"] == "detector" and side["declared"] == "cam0"
    assert 0.0 <= side["probability_cam0"] <= 1.0 and 0.0 <= side["probability_cam1"] <= 1.0
    assert side["num_frames"] > 0


@pytest.mark.slow
def test_swapped_side_is_flagged_on_light_rain(swapped: dict[str, Any]) -> None:
    side = swapped["side"]
    assert side["inferred"] == "cam1"
    assert side["mismatch"] is True and side["agrees"] is False
