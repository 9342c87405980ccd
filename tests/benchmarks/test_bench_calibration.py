"""bench_calibration times detection + calibration per run and quotes the median of the sums."""

from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from benchmarks import bench_calibration


def test_detection_plus_calibration_is_the_median_of_each_runs_sum(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # the README's "median" was the detection median plus the calibration median
    detect, calibrate = [1.0, 10.0, 2.0], [10.0, 1.0, 3.0]  # sums 11, 11, 5: median 11
    ticks: list[float] = []
    for d, c in zip(detect, calibrate, strict=True):
        ticks += [0.0, d, 0.0, c, 0.0, 1.0]  # start and end of detect, calibrate, recording
    clock: Iterator[float] = iter(ticks)
    monkeypatch.setattr(
        bench_calibration,
        "time",
        SimpleNamespace(perf_counter=lambda: next(clock), process_time=lambda: 0.0),
    )
    truth = bench_calibration.make_rig("radtan")
    image = np.zeros((8, 8), np.uint8)
    monkeypatch.setattr(bench_calibration, "render_views", lambda *args: [(image, image)])
    monkeypatch.setattr(bench_calibration, "detect_views", lambda *args: None)
    monkeypatch.setattr(bench_calibration, "calibrate_recording", lambda *args, **kw: None)
    result = SimpleNamespace(
        cameras=[SimpleNamespace(camera=truth.cam0), SimpleNamespace(camera=truth.cam1)],
        rig=truth, counts={"both_detected": 1}, stereo_rms_px=0.1, row_disagreement_px=0.1,
    )  # fmt: skip

    def calibrated(*args: Any) -> SimpleNamespace:
        return result

    monkeypatch.setattr(bench_calibration, "calibrate_from_detections", calibrated)
    case = bench_calibration.run_case("chessboard:9x6:0.06", "pinhole-radtan", 1, 3)
    assert case["detect_ms"] == 2000.0 and case["calibrate_ms"] == 3000.0  # medians apart
    assert case["detect_calibrate_ms"] == 11000.0  # not 5000: a median of the sums
    assert case["repeats"] == 3 and case["opencv_threads"] >= 1
