"""Reading a bag cut short (a recorder killed, a copy interrupted) up to the cut.

``rosbags`` opens a ROS1 or MCAP file through the index written at its end,
and SQLite refuses a ``.db3`` whose last pages are missing, so a cut bag
cannot be opened at all. :func:`salvage_bag` reads the file record by record
from the start instead and keeps every message whose record is complete:

* ROS1 ``.bag``: bag header, chunk (``none``/``bz2``/``lz4``), connection and
  message records, parsed with ``rosbags.rosbag1`` helpers. In a chunk cut
  short, the complete messages of an uncompressed chunk are kept; a
  compressed one cannot be decompressed and is lost.
* MCAP: schema, channel, message and chunk records (the same rule for a cut
  chunk), parsed with ``rosbags.rosbag2.storage_mcap`` helpers.
* ``.db3``: the whole pages before the cut are copied to a temporary file
  whose header says so; SQLite then reads rows in id order and stops with an
  error at the first row that needs a missing page, so no row is returned
  with bytes that were not in the file.

The result quacks like the parts of ``rosbags.highlevel.AnyReader`` that
:mod:`lenspair.capture.rosbag` uses (``topics``, ``connections``,
``messages``, ``deserialize``, ``close``) and carries :attr:`SalvagedBag.cut`,
one line naming the file and where reading stopped.
"""

import os
import sqlite3
import struct
import tempfile
from collections.abc import Collection, Generator
from io import BytesIO
from pathlib import Path
from typing import Any, NamedTuple

from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag1,
    ConnectionExtRosbag2,
    MessageDefinition,
    MessageDefinitionFormat,
)
from rosbags.rosbag1.reader import Header, RecordType, decompressors, normalize, read_uint32
from rosbags.rosbag2.storage_mcap import Schema, decompress, get_msgdef, get_qos
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.msg import normalize_msgtype

from lenspair.capture.errors import CaptureError

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_ROS1_MAGIC = b"#ROSBAG V2.0\n"
_SQLITE_MAGIC = b"SQLite format 3\x00"


class _Topic(NamedTuple):
    """What :mod:`lenspair.capture.rosbag` reads of a topic."""

    msgtype: str


class _Entry(NamedTuple):
    """One complete message: where its payload lies.

    ``chunk`` is -1 for bytes read straight from the file at ``offset``, the
    index of a decompressed chunk otherwise, or -2 for a ``.db3`` row id.
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
    """

    def __init__(self, path: Path, storage: Path) -> None:
        self.path = path
        self.storage = storage
        self.is_ros1 = storage.suffix.lower() == ".bag"
        self.connections: list[Connection] = []
        self.topics: dict[str, _Topic] = {}
        self.cut = ""
        self._entries: list[_Entry] = []
        self._chunks: list[tuple[int, int, str, int, int]] = []  # pos, size, codec, usize, crc
        self._cached: tuple[int, bytes] = (-1, b"")
        self._bio = storage.open("rb")
        self._db: sqlite3.Connection | None = None
        self._typestore: Any = None

    def messages(
        self,
        connections: Collection[Connection] = (),
        start: int | None = None,
        stop: int | None = None,
    ) -> Generator[tuple[Connection, int, bytes], None, None]:
        """``(connection, log_time_ns, raw)`` in log-time order, like ``AnyReader``."""
        wanted = {c.id for c in connections} if connections else None
        for entry in self._entries:
            if wanted is not None and entry.connection.id not in wanted:
                continue
            if (start is not None and entry.log_time < start) or (
                stop is not None and entry.log_time >= stop
            ):
                continue
            yield entry.connection, entry.log_time, self._payload(entry)

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        """Deserialise a message with the bag's own definitions (ROS1 or CDR)."""
        if self.is_ros1:
            return self._typestore.deserialize_ros1(raw, msgtype)
        return self._typestore.deserialize_cdr(raw, msgtype)

    def close(self) -> None:
        """Release the file (and the SQLite copy)."""
        self._bio.close()
        if self._db is not None:
            self._db.close()

    def _payload(self, entry: _Entry) -> bytes:
        if entry.chunk == -2:
            assert self._db is not None
            (data,) = self._db.execute(
                "SELECT data FROM messages WHERE id = ?", (entry.offset,)
            ).fetchone()
            return bytes(data)
        if entry.chunk == -1:
            self._bio.seek(entry.offset)
            return self._bio.read(entry.size)
        if self._cached[0] != entry.chunk:
            self._cached = (entry.chunk, self._decompress(entry.chunk))
        return self._cached[1][entry.offset : entry.offset + entry.size]

    def _decompress(self, index: int) -> bytes:
        pos, size, codec, usize, crc = self._chunks[index]
        self._bio.seek(pos)
        data = self._bio.read(size)
        if self.is_ros1:
            return decompressors[codec](data)
        return decompress(data, codec, usize, crc)

    def _add(
        self, connection: Connection, log_time: int, chunk: int, offset: int, size: int
    ) -> None:
        self._entries.append(_Entry(log_time, len(self._entries), connection, chunk, offset, size))

    def _add_connection(self, connection: Connection) -> None:
        self.connections.append(connection)
        self.topics.setdefault(connection.topic, _Topic(connection.msgtype))

    def _finish(self, stopped_at: int, why: str) -> None:
        self._entries.sort(key=lambda e: (e.log_time, e.order))
        size = self.storage.stat().st_size
        self.cut = (
            f"{self.storage}: cut short ({size} bytes): kept the {len(self._entries)} complete "
            f"messages before byte {stopped_at}; {why}"
        )
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


def salvage_bag(path: Path) -> SalvagedBag:
    """Open the complete messages of a bag that ``rosbags`` cannot open.

    Args:
        path: ``.bag``/``.db3``/``.mcap`` file, or a ROS 2 folder holding one.

    Raises:
        CaptureError: not one readable storage file, or no complete message.
    """
    path = Path(path)
    storage = _storage_file(path)
    bag = SalvagedBag(path, storage)
    try:
        with storage.open("rb") as bio:
            magic = bio.read(16)
            bio.seek(0)
            if magic.startswith(_ROS1_MAGIC):
                _scan_ros1(bag, bio)
            elif magic.startswith(_MCAP_MAGIC):
                _scan_mcap(bag, bio)
            elif magic.startswith(_SQLITE_MAGIC):
                _scan_db3(bag)
            else:
                raise CaptureError(f"{storage}: not a ROS1, MCAP or SQLite bag (file magic)")
    except BaseException:
        bag.close()
        raise
    if not bag._entries:
        bag.close()
        raise CaptureError(f"{bag.cut or storage}: no complete message")
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
    if len(head) < 100 or not head.startswith(_SQLITE_MAGIC):
        return False
    (page_size,) = struct.unpack_from(">H", head, 16)
    (pages,) = struct.unpack_from(">L", head, 28)
    return storage.stat().st_size < (65536 if page_size == 1 else int(page_size)) * int(pages)


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


def _scan_ros1(bag: SalvagedBag, bio: Any) -> None:
    size = bag.storage.stat().st_size
    bio.readline()
    known: dict[int, Connection] = {}
    stopped_at, why = bio.tell(), "end of the records"
    while bio.tell() < size:
        start = bio.tell()
        try:
            header = Header.read(bio)
            op = header.get_uint8("op")
            if op == RecordType.CONNECTION:
                _ros1_connection(bag, known, header, Header.read(bio))
                stopped_at = bio.tell()
                continue
            length = read_uint32(bio)
        except Exception:
            why = f"the record at byte {start} is incomplete"
            break
        datapos = bio.tell()
        complete = datapos + length <= size
        if op == RecordType.CHUNK:
            codec = header.get_string("compression")
            if codec == "none":
                got = bio.read(min(length, size - datapos))
                stopped_at = datapos + _ros1_records(bag, known, got, -1, datapos)
            elif complete and codec in decompressors:
                bag._chunks.append((datapos, length, codec, 0, 0))
                raw = decompressors[codec](bio.read(length))
                _ros1_records(bag, known, raw, len(bag._chunks) - 1, 0)
                stopped_at = datapos + length
        elif op == RecordType.MSGDATA and complete and header.get_uint32("conn") in known:
            connection = known[header.get_uint32("conn")]
            bag._add(connection, header.get_time("time"), -1, datapos, length)
            stopped_at = datapos + length
        elif complete:
            stopped_at = datapos + length
        if not complete:
            why = f"the {RecordType(op).name.lower()} record at byte {start} is incomplete"
            break
        bio.seek(datapos + length)
    bag._finish(stopped_at, why)


def _ros1_records(
    bag: SalvagedBag, known: dict[int, Connection], data: bytes, chunk: int, base: int
) -> int:
    """Add the complete records of a chunk's data; returns where they end."""
    buf = BytesIO(data)
    end = 0
    while buf.tell() < len(data):
        try:
            header = Header.read(buf)
            if header.get_uint8("op") == RecordType.CONNECTION:
                _ros1_connection(bag, known, header, Header.read(buf))
            else:
                length = read_uint32(buf)
                if buf.tell() + length > len(data):
                    break
                if header.get_uint8("op") == RecordType.MSGDATA:
                    connection = known[header.get_uint32("conn")]
                    bag._add(connection, header.get_time("time"), chunk, base + buf.tell(), length)
                buf.seek(length, os.SEEK_CUR)
        except Exception:
            break
        end = buf.tell()
    return end


def _ros1_connection(
    bag: SalvagedBag, known: dict[int, Connection], header: Header, data: Header
) -> None:
    conn = header.get_uint32("conn")
    if conn in known:
        return
    msgtype = normalize_msgtype(data.get_string("type"))
    callerid = data.get_string("callerid") if "callerid" in data else None
    latching = data.get_string("latching") if "latching" in data else ""
    connection = Connection(
        conn,
        normalize(header.get_string("topic")),
        msgtype,
        MessageDefinition(MessageDefinitionFormat.MSG, data.get_string("message_definition")),
        data.get_string("md5sum"),
        0,
        ConnectionExtRosbag1(callerid, int(latching) if latching else None),
        bag,
    )
    known[conn] = connection
    bag._add_connection(connection)


def _scan_mcap(bag: SalvagedBag, bio: Any) -> None:
    size = bag.storage.stat().st_size
    bio.seek(len(_MCAP_MAGIC))
    schemas: dict[int, Schema] = {}
    known: dict[int, Connection] = {}
    stopped_at, why = bio.tell(), "end of the records"
    while bio.tell() < size:
        start = bio.tell()
        head = bio.read(9)
        if len(head) < 9:
            why = f"the record at byte {start} is incomplete"
            break
        op, length = struct.unpack("<BQ", head)
        if op in (0x02, 0x0F):  # footer, data end: the data section is whole
            why = "the cut lies after the data section"
            break
        content = bio.read(min(length, size - start - 9))
        complete = len(content) == length
        if op == 0x06:
            used = _mcap_chunk(bag, schemas, known, content, start + 9, complete)
            if complete or used:
                stopped_at = used if not complete else start + 9 + length
        elif complete:
            try:
                _mcap_record(bag, schemas, known, op, content, -1, start + 9)
            except Exception:
                why = f"the record at byte {start} is damaged"
                break
            stopped_at = start + 9 + length
        if not complete:
            name = "chunk record" if op == 0x06 else "record"
            why = f"the {name} at byte {start} is incomplete"
            break
    bag._finish(stopped_at, why)


def _mcap_chunk(
    bag: SalvagedBag,
    schemas: dict[int, Schema],
    known: dict[int, Connection],
    content: bytes,
    base: int,
    complete: bool,
) -> int:
    """Add a chunk's complete records; returns the file byte they end at (0: none)."""
    if len(content) < 32:
        return 0
    _, _, usize, crc, name_size = struct.unpack_from("<QQQIL", content)
    codec = content[32 : 32 + name_size].decode()
    offset = 32 + name_size + 8
    records = content[offset:]
    if codec:
        if not complete:
            return 0
        bag._chunks.append((base + offset, len(records), codec, usize, crc))
        records = decompress(records, codec, usize, crc)
        chunk, where = len(bag._chunks) - 1, 0
    else:
        chunk, where = -1, base + offset
    end = 0
    pos = 0
    while pos + 9 <= len(records):
        op, length = struct.unpack_from("<BQ", records, pos)
        if pos + 9 + length > len(records):
            break
        try:
            _mcap_record(
                bag, schemas, known, op, records[pos + 9 : pos + 9 + length], chunk, where + pos + 9
            )
        except Exception:
            break
        pos += 9 + length
        end = pos
    return base + offset + end if chunk == -1 else base + len(content)


def _mcap_record(
    bag: SalvagedBag,
    schemas: dict[int, Schema],
    known: dict[int, Connection],
    op: int,
    record: bytes,
    chunk: int,
    offset: int,
) -> None:
    """Take in a schema, channel or message record (``offset``: its content)."""
    if op == 0x03:
        rec = BytesIO(record)
        (key,) = struct.unpack("<H", rec.read(2))
        schemas[key] = Schema(key, _string(rec), _string(rec), _string(rec))
    elif op == 0x04:
        rec = BytesIO(record)
        key, schema_id = struct.unpack("<HH", rec.read(4))
        topic, encoding = _string(rec), _string(rec)
        (map_size,) = struct.unpack("<L", rec.read(4))
        metadata = struct.pack("<L", map_size) + rec.read(map_size)
        schema = schemas.get(schema_id)
        connection = Connection(
            key,
            topic,
            schema.name if schema else "__schemaless__",
            get_msgdef(schema),
            "",
            0,
            ConnectionExtRosbag2(encoding, get_qos(metadata[4:])),
            bag,
        )
        if key not in known:
            known[key] = connection
            bag._add_connection(connection)
    elif op == 0x05:
        channel, _, log_time, _ = struct.unpack_from("<HLQQ", record)
        if channel in known:
            bag._add(known[channel], log_time, chunk, offset + 22, len(record) - 22)


def _string(rec: BytesIO) -> str:
    (size,) = struct.unpack("<L", rec.read(4))
    return rec.read(size).decode()


def _scan_db3(bag: SalvagedBag) -> None:
    data_size = bag.storage.stat().st_size
    with bag.storage.open("rb") as bio:
        head = bio.read(100)
        (page_size,) = struct.unpack_from(">H", head, 16) if len(head) == 100 else (0,)
        page_size = 65536 if page_size == 1 else page_size
        pages = data_size // page_size if page_size else 0
        if not pages:
            raise CaptureError(
                f"{bag.storage}: cut short ({data_size} bytes) inside its first page"
            )
        bio.seek(0)
        handle, name = tempfile.mkstemp(suffix=".db3", prefix="lenspair-salvage-")
        try:
            with os.fdopen(handle, "wb") as out:  # whole pages only, streamed
                left = pages * page_size
                while left:
                    block = bio.read(min(left, 1 << 20))
                    if not block:  # the file shrank while being read
                        break
                    out.write(block)
                    left -= len(block)
                out.seek(28)  # the header's page count: SQLite stops at the last page
                out.write(struct.pack(">L", pages))
            db = sqlite3.connect(f"file:{name}?immutable=1", uri=True, check_same_thread=False)
        finally:
            os.unlink(name)  # the open connection keeps the data until it closes
    bag._db = db
    why = "end of the rows"
    try:
        known = _db3_connections(bag, db)
        # Reading ``data`` makes SQLite fetch every page of the row.
        rows = db.execute("SELECT id, topic_id, timestamp, data FROM messages ORDER BY id")
        for row_id, topic_id, log_time, _ in rows:
            if topic_id in known:
                bag._add(known[topic_id], log_time, -2, row_id, 0)
    except sqlite3.DatabaseError as exc:
        why = f"SQLite stops at the missing pages ({exc})"
    bag._finish(pages * page_size, why)


def _db3_connections(bag: SalvagedBag, db: sqlite3.Connection) -> dict[int, Connection]:
    definitions: dict[str, tuple[str, str]] = {}
    try:
        for msgtype, encoding, text in db.execute(
            "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
        ):
            definitions[msgtype] = (encoding, text)
    except sqlite3.DatabaseError:  # older schema, or the table lies past the cut
        pass
    known: dict[int, Connection] = {}
    for key, topic, msgtype, fmt in db.execute(
        "SELECT id, name, type, serialization_format FROM topics"
    ):
        encoding, text = definitions.get(msgtype, ("", ""))
        kind = {"ros2msg": MessageDefinitionFormat.MSG, "ros2idl": MessageDefinitionFormat.IDL}
        msgdef = MessageDefinition(kind.get(encoding, MessageDefinitionFormat.NONE), text)
        connection = Connection(
            key, topic, msgtype, msgdef, "", 0, ConnectionExtRosbag2(fmt, []), bag
        )
        known[key] = connection
        bag._add_connection(connection)
    return known
