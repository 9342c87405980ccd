"""Loading bag frames through per-topic cursors: right pixels in any order, one pass in order."""

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lenspair.capture import rosbag
from lenspair.capture.bag_cursor import AHEAD, Message, OpenBags, Place
from lenspair.capture.recording import FrameRef, load_frame, open_recording
from lenspair.capture.rosbag import close_bag_readers, open_bag
from tests.capture.test_rosbag import IMAGE, KINDS, MS, T0, _image, _raw_fields, _write_bag

FRAMES = AHEAD + 40
"""Frames per camera: enough for a jump past :data:`AHEAD`."""
SHARED_LOG = range(10, 13)
"""cam0 frames received at one log time (stamps differ): their occurrences are 0, 1, 2."""


def _bag(path: Path, kind: str) -> Path:
    messages = []
    for i in range(FRAMES):
        t = T0 + i * 50 * MS
        fields = _raw_fields(_image(i), "mono8")
        if i in SHARED_LOG:
            fields["_log_ns"] = T0 + SHARED_LOG[0] * 50 * MS
        messages.append(("/cam0/image_raw", IMAGE, t, fields))
        messages.append(
            ("/cam1/image_raw", IMAGE, t + 2 * MS, _raw_fields(_image(1000 + i), "mono8"))
        )
    return _write_bag(path / kind, kind, messages)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> dict[str, list[FrameRef]]:
    """Per bag kind, every frame: cam0's then cam1's, each in time order."""
    folder = tmp_path_factory.mktemp("bags")
    frames = {}
    for kind in KINDS:
        recording = open_recording(_bag(folder, kind))
        frames[kind] = recording.frames["cam0"] + recording.frames["cam1"]
    return frames


def _expected(index: int) -> np.ndarray:
    return _image(index) if index < FRAMES else _image(1000 + index - FRAMES)


def test_frames_at_one_log_time_are_told_apart(recordings: dict[str, list[FrameRef]]) -> None:
    shared = recordings["ros1"][SHARED_LOG[0] : SHARED_LOG[-1] + 1]
    assert len({f.log_time_ns for f in shared}) == 1
    assert [f.occurrence for f in shared] == [0, 1, 2]


@settings(max_examples=30, deadline=None)
@given(
    kind=st.sampled_from(KINDS),
    order=st.lists(st.integers(0, 2 * FRAMES - 1), min_size=1, max_size=40),
)
def test_any_order_of_loads_gives_each_frame_its_pixels(
    recordings: dict[str, list[FrameRef]], kind: str, order: list[int]
) -> None:
    frames = recordings[kind]
    for index in order:
        np.testing.assert_array_equal(load_frame(frames[index]), _expected(index))


class _CountingReader:
    """A bag reader that counts the queries asked of it."""

    def __init__(self, reader: Any) -> None:
        self.reader = reader
        self.queries = 0

    def messages(self, connections: Any, **bounds: int) -> Iterator[Message]:
        self.queries += 1
        return self.reader.messages(connections, **bounds)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.reader, name)


@pytest.mark.parametrize("kind", KINDS)
def test_loading_in_order_reads_each_topic_in_one_pass(
    recordings: dict[str, list[FrameRef]], kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    opened: list[_CountingReader] = []

    def counting_open(path: Path) -> _CountingReader:
        opened.append(_CountingReader(open_bag(path)))
        return opened[-1]

    close_bag_readers()
    monkeypatch.setattr(rosbag, "_CACHE", OpenBags(size=4, opener=counting_open))
    frames = recordings[kind]
    for cam0, cam1 in zip(frames[:FRAMES], frames[FRAMES:], strict=True):
        np.testing.assert_array_equal(load_frame(cam1), _expected(frames.index(cam1)))
        np.testing.assert_array_equal(load_frame(cam0), _expected(frames.index(cam0)))
    assert [reader.queries for reader in opened] == [2]  # one per topic, for every frame
    load_frame(frames[0])  # behind the cursor
    assert opened[0].queries == 3
    load_frame(frames[1])  # the next one: read on
    load_frame(frames[1 + AHEAD + 1])  # too far ahead: asked anew
    assert opened[0].queries == 4
    rosbag.close_bag_readers()


class _ListReader:
    """A reader of one topic whose messages are at ``times`` (sorted)."""

    def __init__(self, times: list[int]) -> None:
        self.times = times

    def messages(self, connections: Any, start: int | None = None) -> Iterator[Message]:
        for index, time in enumerate(self.times):
            if start is None or time >= start:
                yield None, time, bytes([index])


@settings(max_examples=200, deadline=None)
@given(
    times=st.lists(st.integers(0, 30), max_size=60).map(sorted),
    wanted=st.lists(st.tuples(st.integers(0, 31), st.integers(0, 3)), min_size=1, max_size=30),
)
def test_a_cursor_finds_what_a_search_from_the_start_finds(
    times: list[int], wanted: list[Place]
) -> None:
    bags = OpenBags(size=1, opener=lambda _: _ListReader(times))
    for place in wanted:
        at_time = [index for index, time in enumerate(times) if time == place[0]]
        expected = at_time[place[1]] if place[1] < len(at_time) else None
        found = bags.message(Path("bag"), "/topic", (), place)
        assert (None if found is None else found[2][0]) == expected


def _scans(bag: Path) -> bool:
    reader = open_bag(bag)
    try:
        return rosbag._scans_one_file(reader)
    finally:
        reader.close()


def test_an_mcap_without_a_summary_keeps_one_query_open(tmp_path: Path) -> None:
    # rosbags scans such a file through one shared file handle: two open queries (cam0's
    # and cam1's) moved each other's place, and frames went missing ("message not found")
    messages = []
    for i in range(30):
        t = T0 + i * 50 * MS
        for camera, value in (("cam0", i), ("cam1", 100 + i)):
            image = np.full((200, 300), value, np.uint8)  # big enough for several chunks
            messages.append((f"/{camera}/image_raw", IMAGE, t, _raw_fields(image, "mono8")))
    bag = _write_bag(tmp_path / "run", "mcap", messages)
    assert not _scans(bag)
    storage = next(bag.glob("*.mcap"))
    data = bytearray(storage.read_bytes())
    data[-37 + 9 : -37 + 17] = (0).to_bytes(8, "little")  # the footer's summary_start: none
    storage.write_bytes(bytes(data))
    assert _scans(bag)  # rosbags' names for its storages still hold
    recording = open_recording(bag)
    close_bag_readers()
    for cam0, cam1 in zip(recording.frames["cam0"], recording.frames["cam1"], strict=True):
        assert int(load_frame(cam0)[0, 0]) + 100 == int(load_frame(cam1)[0, 0])
    close_bag_readers()
