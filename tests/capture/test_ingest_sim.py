"""End-to-end ingest of the simulated rain sample: accuracy, reruns, workers."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingested import read_pairs
from lenspair.cli import main
from lenspair.core.imagewrite import write_image
from lenspair.rectify.registration import EstimationParams
from tests.capture.ingest_helpers import registration_errors, simulate, tree_bytes

MAX_MEDIAN_ERROR_PX = 0.25
FEW_FRAMES = EstimationParams(max_frames=3)  # keeps the test fast; the default pools 30
SAMPLES = Path(__file__).resolve().parents[2] / "calib_samples"


@pytest.fixture(scope="module")
def rain(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The rain sample (6 frames) and its ingest with one worker."""
    root = tmp_path_factory.mktemp("rain")
    recording = simulate("rain", root / "rain", frames=6)
    ingest_recording(recording, root / "out", workers=1, estimation=FEW_FRAMES)
    return recording, root / "out" / "rain"


def test_rain_registration_error_is_subpixel(rain: tuple[Path, Path]) -> None:
    recording, out_dir = rain
    kept = [r for r in read_pairs(out_dir / "pairs.jsonl") if r.status == "kept"]
    assert len(kept) >= 4  # cam1 drops frames in this sample: fewer pairs than frames
    errors = registration_errors(recording, out_dir)
    median = float(np.median(np.concatenate(list(errors.values()))))
    print(f"rain: median registration error {median:.4f} px over {len(errors)} frames")
    assert median < MAX_MEDIAN_ERROR_PX
    assert max(float(np.median(e)) for e in errors.values()) < MAX_MEDIAN_ERROR_PX
    assert all(r.mask_fraction is not None and r.mask_fraction < 0.02 for r in kept)


def test_full_rerun_is_byte_identical(rain: tuple[Path, Path]) -> None:
    recording, out_dir = rain
    before = tree_bytes(out_dir)
    ingest_recording(recording, out_dir.parent, workers=1, estimation=FEW_FRAMES)
    assert tree_bytes(out_dir) == before


def test_two_workers_give_identical_outputs(rain: tuple[Path, Path], tmp_path: Path) -> None:
    recording, out_dir = rain
    ingest_recording(recording, tmp_path, workers=2, estimation=FEW_FRAMES)
    ours, theirs = tree_bytes(out_dir), tree_bytes(tmp_path / "rain")
    assert ours.keys() == theirs.keys()
    assert [name for name in ours if ours[name] != theirs[name]] == ["report.json"]
    reports = [json.loads(files["report.json"]) for files in (ours, theirs)]
    for report in reports:
        del report["timings_s"]  # wall-clock times are the only difference
    assert reports[0] == reports[1]


def test_a_periodic_wall_that_registers_a_period_off_is_flagged(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, rain: tuple[Path, Path]
) -> None:
    rows, columns = np.mgrid[0:256, 0:256]
    write_image(
        tmp_path / "checker.png", (((rows // 16 + columns // 16) % 2) * 200 + 30).astype(np.uint8)
    )
    scene = yaml.safe_load((SAMPLES / "clean.yaml").read_text())
    scene["planes"][0].update(texture=str(tmp_path / "checker.png"), tile_m=[55.0, 55.0])
    (tmp_path / "checker.yaml").write_text(yaml.safe_dump(scene))
    assert main(["simulate", str(tmp_path / "checker.yaml"), "--out", str(tmp_path / "rec"),
                 "--frames", "6"]) == 0  # fmt: skip
    with caplog.at_level("WARNING"):
        report = ingest_recording(tmp_path / "rec", tmp_path / "out", estimation=FEW_FRAMES)
    counts = report.counts
    assert counts["homography_inliers"] < 0.5 * counts["homography_matches"]
    # one period off, yet every frame kept: the warning is all a user gets
    (said,) = [
        r.getMessage() for r in caplog.records if "agree with the homography" in r.getMessage()
    ]
    assert "repetitive scene" in said and "qa.png" in said
    # a recording registered right is not flagged
    caplog.clear()
    with caplog.at_level("WARNING"):
        ingest_recording(rain[0], tmp_path / "out2", workers=1, estimation=FEW_FRAMES)
    assert not any("agree with the homography" in r.getMessage() for r in caplog.records)


def test_heavy_rain_declared_right_builds_with_the_detail_hint_as_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # heavy_rain seed 13: the fine-detail check names the clean camera (the drops' rims
    # add detail) with confidence 0.52; dataset-build refused the right declaration and
    # told the user to swap it, while the wrong one got "images agree" and built
    recording = tmp_path / "h13"
    spec = str(SAMPLES / "heavy_rain.yaml")
    assert main(["simulate", spec, "--out", str(recording), "--frames", "8", "--seed", "13"]) == 0
    report = ingest_recording(recording, tmp_path / "ing")
    side = report.side_check
    assert (side["declared"], side["inferred"], side["method"]) == ("cam1", "cam0", "detail")
    assert side["confidence"] >= 0.5 and "images agree" not in side["message"]
    assert "a hint, not a check" in side["message"]
    out = tmp_path / "DS"
    with caplog.at_level("WARNING"):
        assert main(["dataset-build", str(tmp_path / "ing" / "h13"), "--out", str(out)]) == 0
    assert any("building as declared, although" in m for m in caplog.messages)
    wrong = ingest_recording(recording, tmp_path / "wrong", obstructed="cam0")
    assert "images agree" not in wrong.side_check["message"]
    assert wrong.side_check["message"].startswith("fine detail is lower on cam0, as declared")
