"""Open bag readers kept per process, with each topic read forward by a cursor.

:func:`lenspair.capture.rosbag.load_bag_frame` finds a frame by its log time
and its place among the topic's messages at that time. Asking the reader
anew for each frame costs time in proportion to the bag's length, because of
how rosbags finds the messages from a time on:

* its ROS 1 reader walks the topic's index from the start;
* its MCAP reader tests every chunk of the file.

Loading every frame of a recording that way costs the square of its length.
A :class:`Cursor` keeps one such query open instead. The next frame of the
topic is usually the next one asked for, since ingest's workers take
consecutive pairs, and it is then the cursor's next message. A frame behind
the cursor, or more than :data:`AHEAD` messages ahead of it, starts a new
query; the frames skipped on the way are read but not decoded. A reader whose
queries share one file position (an MCAP file without a chunk index, which
rosbags reads by scanning it) keeps one open query at a time: two would move
each other's place and skip messages.
"""

import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Collection, Iterator
from contextlib import suppress
from pathlib import Path
from typing import Any

Message = tuple[Any, int, bytes]
"""``(connection, log_time_ns, raw)``, as ``reader.messages`` yields them."""
Place = tuple[int, int]
"""Where a message is: its log time (ns) and its index among the topic's messages at that time."""

AHEAD = 64
"""The most messages a cursor reads past to reach a frame before a new query is cheaper."""


class Cursor:
    """The messages of one topic from a log time on, read one at a time.

    Args:
        messages: ``reader.messages(connections, start=t)`` for one topic's
            connections: every message at ``t`` and after, in log-time order.
    """

    def __init__(self, messages: Iterator[Message]) -> None:
        self._messages = messages
        self.head: Message | None = next(messages, None)
        """The next message not passed over (None: none is left)."""
        self._occurrence = 0

    @property
    def place(self) -> Place | None:
        """The :data:`Place` of :attr:`head` (None: none is left)."""
        return None if self.head is None else (self.head[1], self._occurrence)

    def seek(self, wanted: Place, limit: int | None) -> tuple[bool, Message | None]:
        """Move forward to ``wanted``.

        Args:
            wanted: the place of the message sought.
            limit: the most messages to pass over (None: no limit).

        Returns:
            ``(reached, message)``. ``reached`` is False when ``wanted`` is
            behind the cursor or more than ``limit`` messages ahead (ask a new
            cursor). Otherwise ``message`` is the one at ``wanted``, or None
            when the topic has no message there.
        """
        place = self.place
        if place is None or place > wanted:
            return False, None
        passed = 0
        while place is not None and place < wanted:
            if limit is not None and passed >= limit:
                return False, None
            self._advance()
            passed += 1
            place = self.place
        return True, self.head if place == wanted else None

    def _advance(self) -> None:
        assert self.head is not None
        time = self.head[1]
        self.head = next(self._messages, None)
        same_time = self.head is not None and self.head[1] == time
        self._occurrence = self._occurrence + 1 if same_time else 0

    def close(self) -> None:
        """End the query (its reader stays open)."""
        with suppress(Exception):
            _end(self._messages)


def first_message(reader: Any, topic: str) -> Message | None:
    """The first message of ``topic`` in an open bag (its query ended), or None when it has none.

    Raises:
        Exception: whatever the reader raises.
    """
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        return None
    messages = reader.messages(connections)
    try:
        return next(messages, None)
    finally:
        _end(messages)


def _end(messages: Iterator[Message]) -> None:
    """End a query of ``reader.messages`` (a generator holds a file position or a cursor)."""
    close = getattr(messages, "close", None)
    if close is not None:
        close()


class OpenBags:
    """A few open readers per process, least recently used closed first, and their cursors.

    Args:
        size: how many readers to keep open.
        opener: opens a bag (:func:`lenspair.capture.rosbag.open_bag`).
        one_query: whether a reader's open queries share one file position,
            so that only one may be open at a time.

    Callers hold :attr:`lock` around every call.
    """

    def __init__(
        self,
        size: int,
        opener: Callable[[Path], Any],
        one_query: Callable[[Any], bool] = lambda reader: False,
    ) -> None:
        self.size = size
        self.opener = opener
        self.one_query = one_query
        self.single: set[Path] = set()
        """Open bags whose reader keeps one query at a time (``one_query``)."""
        self.lock = threading.Lock()
        self.readers: OrderedDict[Path, Any] = OrderedDict()
        self.cursors: dict[tuple[Path, str], Cursor] = {}
        self.pid = os.getpid()
        self.inherited: list[Any] = []

    def get(self, bag: Path) -> Any:
        """The open reader of ``bag``, opened now if it is not."""
        if self.pid != os.getpid():
            # A forked child must not use (or close) its parent's file handles.
            self.inherited.extend([*self.readers.values(), *self.cursors.values()])
            self.readers.clear()
            self.cursors.clear()
            self.single.clear()
            self.pid = os.getpid()
        if bag in self.readers:
            self.readers.move_to_end(bag)
            return self.readers[bag]
        reader = self.opener(bag)
        self.readers[bag] = reader
        if self.one_query(reader):
            self.single.add(bag)
        while len(self.readers) > self.size:
            oldest = next(iter(self.readers))
            self._close(oldest)
        return reader

    def message(
        self, bag: Path, topic: str, connections: Collection[Any], wanted: Place
    ) -> Message | None:
        """The message of ``topic`` at ``wanted``, or None when the bag has none there.

        Raises:
            Exception: whatever the reader raises (the topic's cursor is dropped).
        """
        reader = self.get(bag)
        key = (bag, topic)
        if bag in self.single:
            for other in [k for k in self.cursors if k[0] == bag and k != key]:
                self._drop_cursor(other)
        try:
            cursor = self.cursors.get(key)
            if cursor is not None:
                reached, message = cursor.seek(wanted, AHEAD)
                if reached:
                    return message
                cursor.close()
            cursor = self.cursors[key] = Cursor(reader.messages(connections, start=wanted[0]))
            return cursor.seek(wanted, None)[1]
        except Exception:
            self._drop_cursor(key)
            raise

    def _drop_cursor(self, key: tuple[Path, str]) -> None:
        cursor = self.cursors.pop(key, None)
        if cursor is not None:
            cursor.close()

    def _close(self, bag: Path) -> None:
        for key in [key for key in self.cursors if key[0] == bag]:
            self._drop_cursor(key)
        reader = self.readers.pop(bag)
        self.single.discard(bag)
        with suppress(Exception):
            reader.close()

    def clear(self) -> None:
        """Close every reader and cursor of this process."""
        for bag in list(self.readers):
            self._close(bag)
