from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.capture.errors import CaptureError
from lenspair.capture.pairing import (
    MIN_FRAME_PERIOD_NS,
    TAKEN,
    PairingResult,
    check_frame_period,
    clock_offset_warning,
    estimate_period_ns,
    pair_frames,
)
from lenspair.capture.recording_types import DUPLICATE_TIMESTAMP
from lenspair.cli import main
from tests.capture.ingest_helpers import CROP, make_recording

MS = 1_000_000


def _accounted(result: PairingResult, n0: int, n1: int) -> None:
    seen0 = [p.index0 for p in result.pairs] + [
        u.index for u in result.unpaired if u.camera == "cam0"
    ]
    seen1 = [p.index1 for p in result.pairs] + [
        u.index for u in result.unpaired if u.camera == "cam1"
    ]
    assert sorted(seen0) == list(range(n0))
    assert sorted(seen1) == list(range(n1))


def test_synchronised_cameras_pair_exactly() -> None:
    ts = [i * 50 * MS for i in range(10)]
    result = pair_frames(ts, ts)
    assert result.period_ns == 50 * MS
    assert result.tolerance_ns == 25 * MS
    assert [(p.index0, p.index1) for p in result.pairs] == [(i, i) for i in range(10)]
    assert result.unpaired == ()


def test_offset_and_dropped_frames_are_reported() -> None:
    ts0 = [i * 50 * MS for i in range(6)]
    ts1 = [t + 3 * MS for t in ts0 if t != 100 * MS] + [1000 * MS]
    result = pair_frames(ts0, ts1)
    assert all(p.dt_ns == 3 * MS for p in result.pairs)
    assert len(result.pairs) == 5
    (missing0,) = result.unpaired_of("cam0")
    assert missing0.t_ns == 100 * MS
    assert missing0.reason == "no cam1 frame within 25.0 ms"
    (extra1,) = result.unpaired_of("cam1")
    assert extra1.reason == "no cam0 frame within 25.0 ms"
    _accounted(result, len(ts0), len(ts1))


def test_conflict_goes_to_the_closer_frame() -> None:
    # Two cam0 frames both near one cam1 frame: the closer wins, the other is told why.
    result = pair_frames([0, 100 * MS, 108 * MS], [0, 104 * MS + 1], tolerance_ns=10 * MS)
    assert [(p.index0, p.index1) for p in result.pairs] == [(0, 0), (2, 1)]
    (loser,) = result.unpaired
    assert (loser.camera, loser.index, loser.reason) == ("cam0", 1, TAKEN)
    assert loser.nearest_dt_ns == 4 * MS + 1


@pytest.mark.parametrize(
    ("ts0", "ts1"),
    [
        # cam1 frames 8 ms and 3.5 ms from cam0's 100 ms: the nearer is the second it meets
        ([93 * MS, 100 * MS, 104 * MS], [92 * MS, 103 * MS + MS // 2]),
        # 3.5 ms and 8 ms: the nearer is the first
        ([95 * MS + MS // 2, 100 * MS, 108 * MS + MS // 2], [96 * MS + MS // 2, 108 * MS]),
    ],
)
def test_a_loser_with_two_candidates_is_told_the_nearer_one(ts0: list[int], ts1: list[int]) -> None:
    # each cam1 frame is taken by a closer cam0 frame
    result = pair_frames(ts0, ts1, tolerance_ns=10 * MS)
    assert [(p.index0, p.index1) for p in result.pairs] == [(0, 0), (2, 1)]
    (loser,) = result.unpaired
    assert (loser.camera, loser.index, loser.reason) == ("cam0", 1, TAKEN)
    assert loser.nearest_dt_ns == 3 * MS + MS // 2


def test_duplicates_are_recorded_not_silently_dropped() -> None:
    result = pair_frames([0, 0, 50 * MS], [0, 50 * MS, 50 * MS], tolerance_ns=5 * MS)
    assert [(p.index0, p.index1) for p in result.pairs] == [(0, 0), (2, 1)]
    reasons = {(u.camera, u.index): u.reason for u in result.unpaired}
    assert reasons == {("cam0", 1): DUPLICATE_TIMESTAMP, ("cam1", 2): DUPLICATE_TIMESTAMP}


def test_unsorted_input_keeps_input_indices() -> None:
    result = pair_frames([100, 0, 50], [51, 101, 1], tolerance_ns=5)
    assert sorted((p.index0, p.index1) for p in result.pairs) == [(0, 1), (1, 2), (2, 0)]
    assert [p.t0_ns for p in result.pairs] == [0, 50, 100]


def test_period_is_robust_to_gaps() -> None:
    ts = [0, 50, 100, 150, 200, 1000, 1050, 1100]
    assert estimate_period_ns(ts, ts) == 50


def test_too_few_frames_or_negative_tolerance_raise() -> None:
    with pytest.raises(CaptureError, match="fewer than two distinct timestamps"):
        pair_frames([5], [5])
    assert len(pair_frames([5], [5], tolerance_ns=0).pairs) == 1
    with pytest.raises(CaptureError, match=">= 0 ns"):
        pair_frames([0, 1], [0, 1], tolerance_ns=-1)


stamps = st.lists(st.integers(min_value=0, max_value=2_000), min_size=0, max_size=25)


@given(stamps, stamps, st.integers(min_value=0, max_value=60))
def test_every_frame_accounted_for_exactly_once(ts0: list[int], ts1: list[int], tol: int) -> None:
    result = pair_frames(ts0, ts1, tolerance_ns=tol)
    _accounted(result, len(ts0), len(ts1))
    for pair in result.pairs:
        assert abs(pair.dt_ns) <= tol
        assert (ts0[pair.index0], ts1[pair.index1]) == (pair.t0_ns, pair.t1_ns)
    # An unmatched frame never has a free partner within tolerance.
    free0 = {u.t_ns for u in result.unpaired_of("cam0") if u.reason != DUPLICATE_TIMESTAMP}
    free1 = {u.t_ns for u in result.unpaired_of("cam1") if u.reason != DUPLICATE_TIMESTAMP}
    assert not any(abs(a - b) <= tol for a in free0 for b in free1)


@given(stamps, stamps, st.integers(min_value=0, max_value=60))
def test_symmetric_under_swapping_cameras(ts0: list[int], ts1: list[int], tol: int) -> None:
    forward = pair_frames(ts0, ts1, tolerance_ns=tol)
    backward = pair_frames(ts1, ts0, tolerance_ns=tol)
    assert {(p.index0, p.index1) for p in forward.pairs} == {
        (p.index1, p.index0) for p in backward.pairs
    }
    swap = {"cam0": "cam1", "cam1": "cam0"}

    def flipped(reason: str) -> str:
        return reason.replace("cam0", "#").replace("cam1", "cam0").replace("#", "cam1")

    assert {(u.camera, u.index, u.reason, u.nearest_dt_ns) for u in forward.unpaired} == {
        (swap[u.camera], u.index, flipped(u.reason), u.nearest_dt_ns) for u in backward.unpaired
    }


@given(st.lists(st.integers(min_value=0, max_value=10**12), min_size=2, max_size=30, unique=True))
def test_default_tolerance_is_half_the_period(ts: list[int]) -> None:
    result = pair_frames(ts, ts)
    assert result.period_ns is not None
    assert result.tolerance_ns == result.period_ns // 2
    assert len(result.pairs) == len(ts)  # identical clocks: all pair with themselves


@pytest.mark.parametrize(
    ("offset_ms", "said"),
    [(0, None), (3, None), (-10, None), (13, "+13.0 ms"), (30, "-20.0 ms"), (-30, "+20.0 ms")],
)
def test_a_clock_offset_of_a_sizeable_part_of_a_frame_is_said(offset_ms: int, said: str) -> None:
    # at 20 Hz a 30 ms offset pairs each frame with the neighbour 20 ms the other way
    ts0 = [i * 50 * MS for i in range(12)]
    ts1 = [t + offset_ms * MS for t in ts0]
    result = pair_frames(ts0, ts1)
    warning = clock_offset_warning(result.pairs, result.period_ns)
    if said is None:
        assert warning is None
    else:
        assert warning is not None and warning.startswith(f"cam1's frames are {said} from cam0's")
        assert "frame period" in warning and "\n" not in warning


def test_timestamps_a_camera_cannot_have_are_refused_naming_the_recording() -> None:
    with pytest.raises(CaptureError, match=r"^rec/x: .* step by 1 ns .* frame numbers"):
        check_frame_period(1, "rec/x")
    check_frame_period(MIN_FRAME_PERIOD_NS, "rec/x")  # 10,000 frames/s: a camera can
    check_frame_period(None, "rec/x")  # one frame per camera: no period to judge


@pytest.mark.parametrize(
    ("stamp", "said"),
    [
        # names like frame0000.png: pairs a frame apart after any drop, so refused
        (lambda index, t_ns: index, "look like frame numbers"),
        # Unix milliseconds step by 50 "ns": the refusal called them frame numbers only
        (lambda index, t_ns: t_ns // 10**6, "Unix times in milli- or microseconds"),
    ],
    ids=["frame numbers", "milliseconds"],
)
def test_capture_ingest_refuses_stamps_no_camera_has_saying_what_they_may_be(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], stamp: Callable[[int, int], int], said: str
) -> None:
    """data.csv stamps a frame or a millisecond apart are refused in one line, nothing written."""
    recording = make_recording(tmp_path / "rec", frames=4)
    for camera in ("cam0", "cam1"):
        listing = recording / "mav0" / camera / "data.csv"
        header, *rows = listing.read_text().splitlines()
        restamped = [
            f"{stamp(index, int(row.split(',')[0]))},{row.split(',')[1]}"
            for index, row in enumerate(rows)
        ]
        listing.write_text("\n".join([header, *restamped]) + "\n")
    assert main(["capture-ingest", str(recording), "--out", str(tmp_path / "out")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert str(recording) in line and said in line
    assert not (tmp_path / "out" / "rec").exists()


def test_a_time_offset_that_pairs_nothing_is_named_as_the_cause(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # it said "no frame of the two cameras could be paired", without a word of the offset
    recording = make_recording(tmp_path / "rec", frames=4)
    args = ["capture-ingest", str(recording), "--out", str(tmp_path / "out")]
    assert main([*args, "--time-offset", "5000"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{recording}: --time-offset 5000 ms leaves no cam0 frame" in line
    assert not (tmp_path / "out" / "rec").exists()


def test_cameras_whose_clocks_pair_nothing_are_named_with_the_time_offset_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # it said "no usable frame pair to register: no frame of the two cameras could be
    # paired", with no word of the clocks, where calibrate names --time-offset
    recording = make_recording(tmp_path / "rec", frames=4)
    listing = recording / "mav0" / "cam1" / "data.csv"
    header, *rows = listing.read_text().splitlines()
    ahead = [f"{int(row.split(',')[0]) + 5 * 10**9},{row.split(',')[1]}" for row in rows]
    listing.write_text("\n".join([header, *ahead]) + "\n")  # cam1's clock 5 s ahead
    args = ["capture-ingest", str(recording), "--out", str(tmp_path / "out")]
    assert main(args) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"{recording}: no cam0 frame lies within pairing tolerance of a cam1 frame" in line
    assert "their middles +5000" in line and "--time-offset" in line
    assert not (tmp_path / "out" / "rec").exists()
    assert main([*args, "--time-offset", "5000", "--size", CROP]) == 0  # as it says


def test_the_period_ignores_repeated_stamps() -> None:
    # a repeated stamp is a zero gap: counted, it pulled the median (and the pairing
    # tolerance) down, and check_frame_period could call a camera's stamps frame numbers
    ms = 1_000_000
    thrice = [t * ms for t in (0, 50, 100, 150) for _ in range(3)]  # a driver repeating them
    assert estimate_period_ns(thrice, [t + 2 * ms for t in thrice]) == 50 * ms
