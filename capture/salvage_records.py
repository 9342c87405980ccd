"""Record-by-record scans of bag files cut short, for :mod:`lenspair.capture.salvage`.

Each scan reads a file from its start, hands every complete connection and
message to the :class:`~lenspair.capture.salvage.SalvagedBag` and ends with
``finish(byte where reading stopped, why)``. A compressed chunk cut short is
recorded with uncompressed size ``CUT_CHUNK``: its data is what
:func:`decompress_prefix` returns of its bytes before the cut.
"""

import bz2
import os
import struct
import sys
from collections.abc import Callable
from io import BytesIO
from typing import TYPE_CHECKING, Any

import lz4.frame
from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag1,
    ConnectionExtRosbag2,
    MessageDefinition,
    MessageDefinitionFormat,
)
from rosbags.rosbag1.reader import Header, RecordType, decompressors, normalize, read_uint32
from rosbags.rosbag2.storage_mcap import Schema, decompress, get_msgdef, get_qos
from rosbags.typesys.msg import normalize_msgtype

if sys.version_info >= (3, 14):
    from compression import zstd
else:
    from backports import zstd  # what rosbags reads MCAP zstd chunks with before 3.14

if TYPE_CHECKING:
    from lenspair.capture.salvage import SalvagedBag

MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
CUT_CHUNK = -1  # uncompressed size recorded for a chunk cut short: decode its prefix

# The streaming decoders of the codecs rosbags reads chunks with (ROS1 lz4
# chunks are lz4 frames, as roslz4 writes them; MCAP lz4 chunks too).
_STREAMING: dict[str, Callable[[], Any]] = {
    "bz2": bz2.BZ2Decompressor,
    "lz4": lz4.frame.LZ4FrameDecompressor,
    "zstd": zstd.ZstdDecompressor,
}


def decompress_prefix(codec: str, data: bytes) -> bytes:
    """All that a streaming decoder returns of the first bytes of a compressed chunk.

    Decoders emit whole blocks: a compressed block whose end is cut gives
    nothing, so up to a block of data before the cut is lost (bz2: a block
    of up to 900 kB, which is usually the whole chunk; lz4 frame: 64 KiB as
    rosbags writes it; zstd: up to 128 KiB). A block stored raw
    (incompressible data) comes out as far as its bytes go.

    Raises:
        KeyError: an unknown codec; the decoder's own error for damaged data.
    """
    decoder = _STREAMING[codec]()
    return bytes(decoder.decompress(data))


def scan_ros1(bag: "SalvagedBag", bio: Any) -> None:
    """Scan a ROS1 bag: header, chunks (their complete records), connections, messages."""
    size = bag.storage.stat().st_size
    bio.readline()
    known: dict[int, Connection] = {}
    stopped_at, why = bio.tell(), "end of the records"
    index_pos = 0
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
            elif codec in decompressors:
                got = bio.read(min(length, size - datapos))
                try:
                    raw = decompressors[codec](got) if complete else decompress_prefix(codec, got)
                except Exception:  # a chunk that does not decompress: damaged, not cut
                    why = f"the chunk record at byte {start} is damaged"
                    break
                bag.chunks.append((datapos, len(got), codec, 0 if complete else CUT_CHUNK, 0))
                kept = bag.message_count
                _ros1_records(bag, known, raw, len(bag.chunks) - 1, 0)
                if complete or bag.message_count > kept:
                    stopped_at = datapos + len(got)
                if not complete:
                    why = _cut_chunk(start, codec, len(got), len(raw), bag.message_count - kept)
                    break
        elif op == RecordType.MSGDATA and complete and header.get_uint32("conn") in known:
            connection = known[header.get_uint32("conn")]
            bag.add_message(connection, header.get_time("time"), -1, datapos, length)
            stopped_at = datapos + length
        elif complete:
            if op == RecordType.BAGHEADER:  # where the index starts (0: never closed)
                index_pos = header.get_uint64("index_pos")
            stopped_at = datapos + length
        if not complete:
            why = f"the {RecordType(op).name.lower()} record at byte {start} is incomplete"
            break
        bio.seek(datapos + length)
    else:  # every record complete; cut only where it ended before the index said it begins
        bag.finish(stopped_at, why, whole=index_pos <= size)
        return
    bag.finish(stopped_at, why)


def _ends_with(bio: Any, size: int, magic: bytes) -> bool:
    """Whether the ``size``-byte file open as ``bio`` ends with ``magic`` (position kept)."""
    where = bio.tell()
    bio.seek(size - len(magic))
    found = bio.read(len(magic)) == magic
    bio.seek(where)
    return bool(found)


def _cut_chunk(start: int, codec: str, got: int, decoded: int, kept: int) -> str:
    """Why reading stopped in a compressed chunk cut short (one line)."""
    return (
        f"the {codec} chunk record at byte {start} is incomplete: its {got} compressed bytes "
        f"before the cut decode to {decoded} bytes holding {kept} complete messages; the "
        f"messages whose compressed bytes reach past them are lost"
    )


def _ros1_records(
    bag: "SalvagedBag", known: dict[int, Connection], data: bytes, chunk: int, base: int
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
                    bag.add_message(
                        connection, header.get_time("time"), chunk, base + buf.tell(), length
                    )
                buf.seek(length, os.SEEK_CUR)
        except Exception:
            break
        end = buf.tell()
    return end


def _ros1_connection(
    bag: "SalvagedBag", known: dict[int, Connection], header: Header, data: Header
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
    bag.add_connection(connection)


def scan_mcap(bag: "SalvagedBag", bio: Any) -> None:
    """Scan an MCAP file: schemas, channels, messages, chunks, up to the data end."""
    size = bag.storage.stat().st_size
    bio.seek(len(MCAP_MAGIC))
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
            if size >= len(MCAP_MAGIC) and _ends_with(bio, size, MCAP_MAGIC):
                why = "the data section is whole"  # and the file ends as one written whole
                bag.finish(stopped_at, why, whole=True)
                return
            break
        content = bio.read(min(length, size - start - 9))
        complete = len(content) == length
        if op == 0x06:
            try:
                used, cut_why = _mcap_chunk(bag, schemas, known, content, start, complete)
            except Exception:  # a chunk that does not decompress: damaged, not cut
                why = f"the chunk record at byte {start} is damaged"
                break
            if complete or used:
                stopped_at = used if not complete else start + 9 + length
            if cut_why:
                why = cut_why
                break
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
    bag.finish(stopped_at, why)


def _mcap_chunk(
    bag: "SalvagedBag",
    schemas: dict[int, Schema],
    known: dict[int, Connection],
    content: bytes,
    start: int,
    complete: bool,
) -> tuple[int, str]:
    """Add a chunk's complete records.

    Returns:
        The file byte they end at (0: none), and for a compressed chunk cut
        short, why reading stopped (else "").
    """
    base = start + 9
    if len(content) < 36:
        return 0, ""
    _, _, usize, crc, name_size = struct.unpack_from("<QQQIL", content)
    offset = 32 + name_size + 8
    if len(content) < offset:  # cut within the codec's name or the records' length
        return 0, ""
    codec = content[32 : 32 + name_size].decode()
    records = content[offset:]
    if codec:
        kept = bag.message_count
        bag.chunks.append(
            (base + offset, len(records), codec, usize if complete else CUT_CHUNK, crc)
        )
        if complete:
            records = decompress(records, codec, usize, crc)
        else:
            records = decompress_prefix(codec, records)
        chunk, where = len(bag.chunks) - 1, 0
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
    if chunk == -1:
        return base + offset + end, ""
    if complete:
        return base + len(content), ""
    got = bag.message_count - kept
    why = _cut_chunk(start, codec, len(content) - offset, len(records), got)
    return (base + len(content) if got else 0), why


def _mcap_record(
    bag: "SalvagedBag",
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
            bag.add_connection(connection)
    elif op == 0x05:
        channel, _, log_time, _ = struct.unpack_from("<HLQQ", record)
        if channel in known:
            bag.add_message(known[channel], log_time, chunk, offset + 22, len(record) - 22)


def _string(rec: BytesIO) -> str:
    (size,) = struct.unpack("<L", rec.read(4))
    return rec.read(size).decode()
