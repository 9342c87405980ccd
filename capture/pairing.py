"""Pairing the frames of two cameras by timestamp, accounting for every frame.

Each cam0 frame is matched to at most one cam1 frame and vice versa. Candidate
matches are the pairs whose timestamps differ by at most ``tolerance_ns``;
they are taken greedily from the smallest time difference up, so a conflict
is always resolved in favour of the closer match. Ties are broken by the
timestamps themselves (smaller first), which makes the result deterministic
and symmetric: swapping the cameras swaps the result.

Every input frame ends up either in exactly one :class:`FramePair` or in
:attr:`PairingResult.unpaired` with one of these reasons (stable strings, fit
for counting):

* ``duplicate timestamp``: an earlier frame of the same camera has the same
  timestamp (the first one takes part in the pairing);
* ``no cam1 frame within 25.0 ms`` (or cam0): nothing close enough;
* ``closer match taken by another frame``: every frame close enough was
  matched to a frame closer to it; ``nearest_dt_ns`` says how close the
  nearest one was.
"""

import bisect
import itertools
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

from lenspair.capture.errors import CaptureError
from lenspair.capture.recording_types import DUPLICATE_TIMESTAMP
from lenspair.capture.rigfile import CameraName

TAKEN = "closer match taken by another frame"


@dataclass(frozen=True)
class FramePair:
    """Two frames taken together.

    Attributes:
        index0: position of the cam0 frame in the ``ts0`` input.
        index1: position of the cam1 frame in the ``ts1`` input.
        t0_ns: cam0 timestamp (ns).
        t1_ns: cam1 timestamp (ns).
    """

    index0: int
    index1: int
    t0_ns: int
    t1_ns: int

    @property
    def dt_ns(self) -> int:
        """``t1_ns - t0_ns`` (ns)."""
        return self.t1_ns - self.t0_ns


@dataclass(frozen=True)
class UnpairedFrame:
    """A frame left without a partner, and why.

    Attributes:
        camera: ``cam0`` or ``cam1``.
        index: position in that camera's input sequence.
        t_ns: its timestamp (ns).
        reason: one of the reasons in the module docstring.
        nearest_dt_ns: for ``closer match taken by another frame``: absolute
            time difference (ns) to the nearest frame of the other camera.
    """

    camera: CameraName
    index: int
    t_ns: int
    reason: str
    nearest_dt_ns: int | None = None


@dataclass(frozen=True)
class PairingResult:
    """Outcome of :func:`pair_frames`.

    Attributes:
        pairs: matched frames, sorted by ``t0_ns``.
        unpaired: frames without a match, sorted by camera, then ``t_ns``,
            then index.
        tolerance_ns: the largest allowed ``|t1 - t0|`` (ns) used.
        period_ns: median frame period (ns) estimated from the data, or None
            when ``tolerance_ns`` was given and there were too few frames.
    """

    pairs: tuple[FramePair, ...]
    unpaired: tuple[UnpairedFrame, ...]
    tolerance_ns: int
    period_ns: int | None

    def unpaired_of(self, camera: CameraName) -> tuple[UnpairedFrame, ...]:
        """The unpaired frames of one camera."""
        return tuple(u for u in self.unpaired if u.camera == camera)


def estimate_period_ns(ts0: Sequence[int], ts1: Sequence[int]) -> int | None:
    """Median difference (ns) of consecutive distinct timestamps of both cameras.

    Returns:
        The period, or None when neither camera has two distinct timestamps.
    """
    gaps: list[int] = []
    for stamps in (ts0, ts1):
        unique = sorted({int(t) for t in stamps})
        gaps.extend(b - a for a, b in itertools.pairwise(unique))
    if not gaps:
        return None
    return round(statistics.median(gaps))


MIN_FRAME_PERIOD_NS = 100_000
"""The shortest frame period taken as a camera's (0.1 ms: 10,000 frames/s); shorter
steps between timestamps are frame counters read as nanoseconds."""


def check_frame_period(period_ns: int | None, where: object) -> None:
    """Refuse timestamps whose median step is no camera's frame period.

    File names like ``frame0000.png`` (what ``image_view extract_images``
    writes) give times 1 ns apart: pairing by them matches frame numbers, and
    once a camera drops a frame every later pair is a frame apart, with no
    warning (the clock-offset check sees them 1 ns apart).
    Times in milliseconds (or microseconds) read as nanoseconds step as fast;
    the folder reader names those itself
    (:func:`lenspair.capture.folders.list_image_folder`), a data.csv does not.

    Raises:
        CaptureError: names ``where`` and says how to give real times.
    """
    if period_ns is not None and period_ns < MIN_FRAME_PERIOD_NS:
        raise CaptureError(
            f"{where}: the frames' timestamps step by {_format_ns(period_ns)} (median), faster "
            f"than any camera ({MIN_FRAME_PERIOD_NS // 1000} us is 10,000 frames/s): they look "
            "like frame numbers (frame0000.png), or Unix times in milli- or microseconds read "
            "as nanoseconds, not times; pairing by them would pair frame numbers, a frame "
            "apart after any dropped frame. Name the images by capture time "
            "in ns or in seconds with a fraction (1403636579763555584.png, "
            "1403636579.763555584.png), or list the times in an EuRoC data.csv"
        )


def pair_frames(
    ts0: Sequence[int], ts1: Sequence[int], tolerance_ns: int | None = None
) -> PairingResult:
    """Match cam0 and cam1 frames one to one by nearest timestamp.

    Args:
        ts0: cam0 timestamps (ns), in any order; duplicates allowed.
        ts1: cam1 timestamps (ns), likewise.
        tolerance_ns: largest ``|t1 - t0|`` (ns) for a match; None uses half
            the median frame period (:func:`estimate_period_ns`).

    Returns:
        The pairs and the unpaired frames; together they hold every index of
        ``ts0`` and ``ts1`` exactly once.

    Raises:
        CaptureError: ``tolerance_ns`` is negative, or it is None and the
            period cannot be estimated (fewer than two distinct timestamps in
            both cameras).
    """
    stamps0 = [int(t) for t in ts0]
    stamps1 = [int(t) for t in ts1]
    period = estimate_period_ns(stamps0, stamps1)
    if tolerance_ns is None:
        if period is None:
            raise CaptureError(
                "cannot estimate the frame period from fewer than two distinct timestamps "
                "per camera; give a pairing tolerance"
            )
        tolerance_ns = period // 2
    if tolerance_ns < 0:
        raise CaptureError(f"pairing tolerance must be >= 0 ns, got {tolerance_ns}")

    unpaired: list[UnpairedFrame] = []
    first0 = _first_indices("cam0", stamps0, unpaired)
    first1 = _first_indices("cam1", stamps1, unpaired)

    # Candidate edges (|dt|, min t, max t, t0, t1): the key is symmetric in the
    # two cameras, and two edges sharing a frame never tie on it.
    sorted1 = sorted(first1)
    edges = []
    nearest: dict[tuple[int, int], int] = {}
    for t0 in first0:
        low = bisect.bisect_left(sorted1, t0 - tolerance_ns)
        high = bisect.bisect_right(sorted1, t0 + tolerance_ns)
        for t1 in sorted1[low:high]:
            gap = abs(t1 - t0)
            edges.append((gap, min(t0, t1), max(t0, t1), t0, t1))
            for key in ((0, t0), (1, t1)):
                nearest[key] = min(nearest.get(key, gap), gap)
    edges.sort()

    matched0: dict[int, int] = {}
    matched1: set[int] = set()
    for _, _, _, t0, t1 in edges:
        if t0 not in matched0 and t1 not in matched1:
            matched0[t0] = t1
            matched1.add(t1)

    pairs = tuple(FramePair(first0[t0], first1[t1], t0, t1) for t0, t1 in sorted(matched0.items()))
    within = _format_ns(tolerance_ns)
    sides: tuple[tuple[int, CameraName, str, dict[int, int], set[int]], ...] = (
        (0, "cam0", "cam1", first0, set(matched0)),
        (1, "cam1", "cam0", first1, matched1),
    )
    for side, camera, other, firsts, matched in sides:
        for t, index in firsts.items():
            if t in matched:
                continue
            gap_ns = nearest.get((side, t))
            if gap_ns is None:
                reason = f"no {other} frame within {within}"
                unpaired.append(UnpairedFrame(camera, index, t, reason))
            else:
                unpaired.append(UnpairedFrame(camera, index, t, TAKEN, gap_ns))
    unpaired.sort(key=lambda u: (u.camera, u.t_ns, u.index))
    return PairingResult(pairs, tuple(unpaired), tolerance_ns, period)


def _first_indices(
    camera: CameraName, stamps: list[int], unpaired: list[UnpairedFrame]
) -> dict[int, int]:
    """Timestamp -> index of its first occurrence; later repeats go to ``unpaired``."""
    first: dict[int, int] = {}
    for index, t in enumerate(stamps):
        if t in first:
            unpaired.append(UnpairedFrame(camera, index, t, DUPLICATE_TIMESTAMP))
        else:
            first[t] = index
    return first


def _format_ns(nanoseconds: int) -> str:
    if nanoseconds >= 100_000:
        return f"{nanoseconds / 1e6:.1f} ms"
    return f"{nanoseconds} ns"


OFFSET_WARNING_SHARE = 0.25
"""Median pairing gap, in frame periods, from which :func:`clock_offset_warning` warns."""


def clock_offset_warning(pairs: Sequence[FramePair], period_ns: int | None) -> str | None:
    """A warning when the cameras' clocks seem to disagree by a sizeable part of a frame.

    Timestamps tell a clock offset only modulo the frame period: cameras whose
    clocks differ by 30 ms at 20 Hz pair each frame with the neighbour taken
    20 ms the other way, one frame apart, with every gap alike. A
    hardware-synchronised rig pairs within a small part of a period; a median
    gap (cam1 - cam0) of a quarter period or more says the pairing may be a
    frame off, which only the images (a moving scene) can tell.

    Returns:
        One line, or None when the pairing is tight or there is nothing to judge.
    """
    if not pairs or not period_ns:
        return None
    median = statistics.median(pair.dt_ns for pair in pairs)
    if abs(median) < OFFSET_WARNING_SHARE * period_ns:
        return None
    return (
        f"cam1's frames are {median / 1e6:+.1f} ms from cam0's on median, "
        f"{abs(median) / period_ns:.0%} of the {_format_ns(period_ns)} frame period: the "
        "cameras' clocks may differ by more than half a period, which timestamps cannot "
        "tell from a one-frame offset, so pairs may be a frame apart; check a moving "
        "scene's pairs (their input and target), and give the offset (--time-offset) "
        "or synchronise the clocks"
    )
