"""End-to-end ingest of the simulated rain sample: accuracy, reruns, workers."""

import json
from pathlib import Path

import numpy as np
import pytest

from lenspair.capture.ingest import ingest_recording
from lenspair.capture.ingested import read_pairs
from lenspair.rectify.registration import EstimationParams
from tests.capture.ingest_helpers import registration_errors, simulate, tree_bytes

MAX_MEDIAN_ERROR_PX = 0.25
FEW_FRAMES = EstimationParams(max_frames=3)  # keeps the test fast; the default pools 30


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
