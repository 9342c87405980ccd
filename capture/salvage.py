"""Reading a bag cut short (a recorder killed, a copy interrupted) up to the cut.

``rosbags`` opens a ROS1 or MCAP file through the index written at its end,
and SQLite refuses a ``.db3`` whose last pages are missing, so a cut bag
cannot be opened at all. :func:`salvage_bag` reads the file record by record
(page by page for SQLite) instead and keeps every message whose bytes all lie
before the cut:

* ROS1 ``.bag``: bag header, chunk (``none``/``bz2``/``lz4``), connection and
  message records, parsed with ``rosbags.rosbag1`` helpers. In a chunk cut
  short, the complete records of an uncompressed chunk are kept; a
  compressed one's bytes before the cut go through the codec's streaming
  decoder, and the complete records of what it returns are kept
  (:func:`~lenspair.capture.salvage_records.decompress_prefix`: decoders
  return whole blocks, so the messages in the block the cut splits, and
  after it, are lost; for bz2 that is usually the whole chunk).
* MCAP: schema, channel, message and chunk records (``lz4``/``zstd`` or
  none: the same rule for a cut chunk), parsed with
  ``rosbags.rosbag2.storage_mcap`` helpers.
* ``.db3``: every table leaf page is read for ``messages`` rows without the
  B-tree above them (:mod:`lenspair.capture.salvage_db3`); a row is kept when
  all of its bytes (its cell and its overflow pages' pieces) lie before the
  cut. The ``topics`` table is read by SQLite from the whole pages before it.

The result quacks like the parts of ``rosbags.highlevel.AnyReader`` that
:mod:`lenspair.capture.rosbag` uses (``topics``, ``connections``,
``messages``, ``deserialize``, ``close``) and carries :attr:`SalvagedBag.cut`,
one line naming the file and where reading stopped.

A scan reads the whole file, so each process keeps the last two scans (keyed
by the file's identity, size, times and end bytes): the commands open a bag
several times (to list its topics, to count, to read), and a cut bag of
gigabytes was read from end to end each time.
"""

import copy
import hashlib
import os
import threading
from bisect import bisect_left
from collections import Counter, OrderedDict
from collections.abc import Collection, Generator
from pathlib import Path
from typing import Any, NamedTuple

from rosbags.interfaces import (
    Connection,
    MessageDefinition,
    MessageDefinitionFormat,
)
from rosbags.rosbag1.reader import decompressors
from rosbags.rosbag2.storage_mcap import decompress
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

from lenspair.capture.errors import CaptureError
from lenspair.capture.salvage_db3 import (
    Db3Layout,
    read_db3_data,
    scan_db3,
    shorter_than_header,
)
from lenspair.capture.salvage_records import (
    CUT_CHUNK,
    MCAP_MAGIC,
    ROS1_MAGIC,
    SQLITE_MAGIC,
    decompress_prefix,
    scan_mcap,
    scan_ros1,
)


class _Topic(NamedTuple):
    """What :mod:`lenspair.capture.rosbag` reads of a topic (as ``rosbags``' ``TopicInfo``)."""

    msgtype: str
    msgcount: int = 0


class _Entry(NamedTuple):
    """One complete message: where its payload lies.

    ``chunk`` is -1 for bytes read straight from the file at ``offset``, the
    index of a decompressed chunk otherwise, or -2 for a ``.db3`` row whose
    cell starts at file byte ``offset``.
    """

    log_time: int
    order: int
    connection: Connection
    chunk: int
    offset: int
    size: int


class SalvagedBag:
    """The complete messages of a bag file cut short, read lazily.

    Attributes:
        path: the bag as given (file or ROS 2 folder).
        storage: the file read.
        connections: connections seen before the cut.
        topics: topic -> info with ``msgtype``.
        cut: one line: file, byte where reading stopped, messages kept, why.
        whole: the scan read the file to its end: nothing was cut (``rosbags``
            refused the bag for another reason, such as a message definition
            naming an undefined type or an unreadable ``metadata.yaml``).
        db3: for a ``.db3``, its page layout (rows are read from the file).
    """

    def __init__(self, path: Path, storage: Path) -> None:
        self.path = path
        self.storage = storage
        self.is_ros1 = False  # told by the file's first bytes (salvage_bag), not its name
        self.connections: list[Connection] = []
        self.topics: dict[str, _Topic] = {}
        self.cut = ""
        self.whole = False
        self.refused = ""  # why rosbags could not open it (lenspair.capture.rosbag.open_bag)
        self._entries: list[_Entry] = []
        self.chunks: list[tuple[int, int, str, int, int]] = []  # pos, size, codec, usize, crc
        self._cached: tuple[int, bytes] = (-1, b"")
        self._bio = storage.open("rb")
        self.db3: Db3Layout | None = None
        self._typestore: Any = None

    def messages(
        self,
        connections: Collection[Connection] = (),
        start: int | None = None,
        stop: int | None = None,
    ) -> Generator[tuple[Connection, int, bytes], None, None]:
        """``(connection, log_time_ns, raw)`` in log-time order, like ``AnyReader``."""
        wanted = {c.id for c in connections} if connections else None
        # Entries are in log-time order: seek to ``start`` (loading one frame
        # must not walk the whole bag).
        first = 0 if start is None else bisect_left(self._entries, start, key=_log_time)
        for index in range(first, len(self._entries)):
            entry = self._entries[index]
            if stop is not None and entry.log_time >= stop:
                return
            if wanted is None or entry.connection.id in wanted:
                yield entry.connection, entry.log_time, self._payload(entry)

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        """Deserialise a message with the bag's own definitions (ROS1 or CDR)."""
        if self.is_ros1:
            return self._typestore.deserialize_ros1(raw, msgtype)
        return self._typestore.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        """Release the file."""
        self._bio.close()

    def _payload(self, entry: _Entry) -> bytes:
        if entry.chunk == -2:
            assert self.db3 is not None
            return read_db3_data(self._bio, self.db3, entry.offset)
        if entry.chunk == -1:
            self._bio.seek(entry.offset)
            return self._bio.read(entry.size)
        if self._cached[0] != entry.chunk:
            self._cached = (entry.chunk, self._decompress(entry.chunk))
        return self._cached[1][entry.offset : entry.offset + entry.size]

    def _decompress(self, index: int) -> bytes:
        pos, size, codec, usize, crc = self.chunks[index]
        self._bio.seek(pos)
        data = self._bio.read(size)
        if usize == CUT_CHUNK:
            return decompress_prefix(codec, data)
        if self.is_ros1:
            return decompressors[codec](data)
        return decompress(data, codec, usize, crc)

    def add_message(
        self, connection: Connection, log_time: int, chunk: int, offset: int, size: int
    ) -> None:
        """Record a complete message (``chunk``/``offset``/``size``: see ``_Entry``)."""
        self._entries.append(_Entry(log_time, len(self._entries), connection, chunk, offset, size))

    def add_connection(self, connection: Connection) -> None:
        """Record a connection read before the cut."""
        self.connections.append(connection)
        self.topics.setdefault(connection.topic, _Topic(connection.msgtype))

    @property
    def message_count(self) -> int:
        """Complete messages found."""
        return len(self._entries)

    def finish(self, stopped_at: int, why: str, whole: bool = False) -> None:
        """Order the messages, write :attr:`cut` (or :attr:`whole`), count topics, build types."""
        self._entries.sort(key=lambda e: (e.log_time, e.order))
        size = self.storage.stat().st_size
        self.whole = whole
        self.cut = (
            f"{self.storage}: read record by record: all {len(self._entries)} messages ({why})"
            if whole
            else f"{self.storage}: cut short ({size} bytes): kept the {len(self._entries)} "
            f"complete messages before byte {stopped_at}; {why}"
        )
        counts = Counter(entry.connection.topic for entry in self._entries)
        self.topics = {name: _Topic(t.msgtype, counts[name]) for name, t in self.topics.items()}
        self._typestore = _typestore(self.connections, self.is_ros1)
        if not self.is_ros1:
            # Writers (restore's copy of the bag) need a definition and hash per
            # connection; a cut MCAP/db3 may not say them, the types do.
            filled = {c.id: self._with_definition(c) for c in self.connections}
            self.connections = list(filled.values())
            self._entries = [e._replace(connection=filled[e.connection.id]) for e in self._entries]

    def _with_definition(self, connection: Connection) -> Connection:
        try:
            text, _ = self._typestore.generate_msgdef(connection.msgtype, ros_version=2)
            digest = self._typestore.hash_rihs01(connection.msgtype)
        except Exception:  # an unknown type: messages are copied, not deserialised
            return connection
        msgdef = connection.msgdef
        if msgdef.format == MessageDefinitionFormat.NONE or not msgdef.data:
            msgdef = MessageDefinition(MessageDefinitionFormat.MSG, text)
        return connection._replace(msgdef=msgdef, digest=connection.digest or digest)


def _log_time(entry: _Entry) -> int:
    return entry.log_time


class _ScanCache:
    """The last few scans of this process, by the storage file's identity."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.lock = threading.Lock()
        self.scans: OrderedDict[tuple[Any, ...], SalvagedBag] = OrderedDict()

    def reopen(self, key: tuple[Any, ...], path: Path) -> SalvagedBag | None:
        """A new reader over an earlier scan of the same file, or None."""
        with self.lock:
            scanned = self.scans.get(key)
            if scanned is None:
                return None
            self.scans.move_to_end(key)
        reader = copy.copy(scanned)  # shares the index, which is never changed after finish
        reader.path = path
        reader._cached = (-1, b"")
        reader._bio = scanned.storage.open("rb")
        return reader

    def keep(self, key: tuple[Any, ...], bag: SalvagedBag) -> None:
        with self.lock:
            self.scans[key] = bag
            while len(self.scans) > self.size:
                self.scans.popitem(last=False)


_SCANS = _ScanCache(size=2)


def _file_key(storage: Path) -> tuple[Any, ...]:
    """The file's identity, size, times and its first and last bytes.

    The bytes guard against a rewrite of the same size within the clock tick
    of the file times (a few milliseconds on Linux).
    """
    with storage.open("rb") as bio:
        stat = os.fstat(bio.fileno())
        head = bio.read(_KEY_BYTES)
        bio.seek(max(stat.st_size - _KEY_BYTES, 0))
        tail = bio.read(_KEY_BYTES)
    times = (stat.st_mtime_ns, stat.st_ctime_ns)
    return (stat.st_dev, stat.st_ino, stat.st_size, times, hashlib.sha256(head + tail).digest())


_KEY_BYTES = 1 << 16


def salvage_bag(path: Path) -> SalvagedBag:
    """Open the complete messages of a bag that ``rosbags`` cannot open.

    Args:
        path: ``.bag``/``.db3``/``.mcap`` file, or a ROS 2 folder holding one.

    Raises:
        CaptureError: not one readable storage file, or no complete message.
    """
    path = Path(path)
    storage = _storage_file(path)
    key = _file_key(storage)
    earlier = _SCANS.reopen(key, path)
    if earlier is not None:
        return earlier
    bag = SalvagedBag(path, storage)
    try:
        with storage.open("rb") as bio:
            magic = bio.read(16)
            bio.seek(0)
            # the file says what it is: a ROS 1 bag's name may end in .bag.active
            bag.is_ros1 = magic.startswith(ROS1_MAGIC)
            if magic.startswith(ROS1_MAGIC):
                scan_ros1(bag, bio)
            elif magic.startswith(MCAP_MAGIC):
                scan_mcap(bag, bio)
            elif magic.startswith(SQLITE_MAGIC):
                scan_db3(bag)
            else:
                raise CaptureError(f"{storage}: not a ROS1, MCAP or SQLite bag (file magic)")
    except BaseException:
        bag.close()
        raise
    if not bag.message_count:
        bag.close()
        raise CaptureError(f"{bag.cut or storage}: no complete message")
    _SCANS.keep(key, bag)
    return bag


def is_cut_db3(path: Path) -> bool:
    """True when ``path`` (a bag) is a ``.db3`` shorter than its SQLite header says.

    SQLite can open such a file and fail only later, part-way through it.
    """
    try:
        storage = _storage_file(Path(path))
        with storage.open("rb") as bio:
            head = bio.read(100)
    except (CaptureError, OSError):
        return False
    return head.startswith(SQLITE_MAGIC) and shorter_than_header(head, storage.stat().st_size)


def _storage_file(path: Path) -> Path:
    if path.is_file():
        return path
    found = sorted(p for p in path.iterdir() if p.suffix.lower() in {".db3", ".mcap"})
    if len(found) != 1:
        raise CaptureError(f"{path}: cannot salvage: need one .db3/.mcap file, found {len(found)}")
    return found[0]


def _typestore(connections: list[Connection], is_ros1: bool) -> Any:
    """The default store of the ROS version plus the bag's own definitions."""
    store = get_typestore(Stores.ROS1_NOETIC if is_ros1 else Stores.ROS2_HUMBLE)
    for connection in connections:
        definition = connection.msgdef
        try:
            if definition.format == MessageDefinitionFormat.MSG and definition.data:
                store.register(get_types_from_msg(definition.data, connection.msgtype))
            elif definition.format == MessageDefinitionFormat.IDL:
                store.register(get_types_from_idl(definition.data))
        except Exception:  # a definition clashing with the store's keeps the store's
            continue
    return store
