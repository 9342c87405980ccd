"""Reading the rows of a ``.db3`` bag cut short, page by page, for :mod:`lenspair.capture.salvage`.

SQLite reaches a row from the table's root through interior B-tree pages and
refuses the row when any page on that path is missing. In a bag those pages
are written late: a leaf page is allocated when the row that overflows it is
inserted, after that row's data, and when the root splits its rows move to a
page at the end of the file written so far. Read through SQLite, a cut loses
the last rows before it and, early in a bag, every row.

So the ``messages`` rows are found without the tree: every table leaf page
(type ``0x0D``) is read, and each cell whose record has the shape of a
``messages`` row (``id`` alias, two integers, a blob) is kept when all of its
bytes lie before the cut: the cell pointer and the cell in the leaf, and the
next-page pointer and payload piece in each overflow page. A row is lost
exactly when one of those bytes is past the cut. Pages on the free list are
skipped (they can hold stale copies of rows); a bag recorder never frees
pages, so this matters only for a ``.db3`` edited after recording.

The small tables (``topics``, ``message_definitions``) are read through
SQLite from a temporary copy of the whole pages before the cut.
"""

import os
import sqlite3
import struct
import tempfile
from typing import IO, TYPE_CHECKING, NamedTuple

from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag2,
    MessageDefinition,
    MessageDefinitionFormat,
)

from lenspair.capture.errors import CaptureError

if TYPE_CHECKING:
    from lenspair.capture.salvage import SalvagedBag

_TABLE_LEAF = 0x0D
_INTEGER_TYPES = frozenset({1, 2, 3, 4, 5, 6, 8, 9})
_INTEGER_SIZES = {0: 0, 1: 1, 2: 2, 3: 3, 4: 4, 5: 6, 6: 8, 8: 0, 9: 0}


class Db3Layout(NamedTuple):
    """What reading a row of a cut ``.db3`` needs to know about the file."""

    page_size: int
    usable: int  # page size less the reserved bytes at each page's end
    size: int  # bytes in the file


def shorter_than_header(head: bytes, size: int) -> bool:
    """Whether a ``.db3`` of ``size`` bytes whose first 100 bytes are ``head`` is cut short.

    SQLite's header counts the file's pages; a count not kept up to date (its
    change counter differs from the one stored beside it) is ignored, as
    SQLite ignores it.
    """
    if len(head) < 100 or head[24:28] != head[92:96]:
        return False
    (page_size,) = struct.unpack_from(">H", head, 16)
    (pages,) = struct.unpack_from(">L", head, 28)
    return size < (65536 if page_size == 1 else int(page_size)) * int(pages)


class _Row(NamedTuple):
    rowid: int
    topic_id: int
    log_time: int
    cell: int  # file byte where the cell starts
    data_size: int


def scan_db3(bag: "SalvagedBag") -> None:
    """Find a cut ``.db3``'s complete ``messages`` rows and hand them to ``bag``."""
    size = bag.storage.stat().st_size
    with bag.storage.open("rb") as bio:
        head = bio.read(100)
        page_size = struct.unpack_from(">H", head, 16)[0] if len(head) == 100 else 0
        page_size = 65536 if page_size == 1 else page_size
        if not page_size or size < page_size:
            raise CaptureError(f"{bag.storage}: cut short ({size} bytes) inside its first page")
        layout = Db3Layout(page_size, page_size - head[20], size)
        bag.db3 = layout
        try:
            known = _db3_connections(bag, bio, size // page_size, page_size)
        except sqlite3.DatabaseError as exc:
            bag.finish(page_size, f"SQLite cannot read the topics table ({exc})")
            return
        rows = _complete_rows(bio, layout, _free_pages(bio, layout, head))
    for row in sorted(rows.values()):
        if row.topic_id in known:
            bag.add_message(known[row.topic_id], row.log_time, -2, row.cell, row.data_size)
    whole = not shorter_than_header(head, size)
    bag.finish(size, "a row with a byte past the cut is lost", whole=whole)


def read_db3_data(bio: IO[bytes], layout: Db3Layout, cell: int) -> bytes:
    """The ``data`` column of the row whose cell starts at file byte ``cell``."""
    row = _read_cell(bio, layout, cell, with_data=True)
    if row is None or isinstance(row, _Row):  # the scan found it complete: the file changed
        raise CaptureError(f"{getattr(bio, 'name', 'db3')}: the row at byte {cell} changed")
    return row


def _complete_rows(bio: IO[bytes], layout: Db3Layout, free: set[int]) -> dict[int, _Row]:
    """Rows of every table leaf page (free pages excepted) with all bytes present, by id."""
    rows: dict[int, _Row] = {}
    for page in range(2, (layout.size - 1) // layout.page_size + 2):
        if page in free:
            continue
        start = (page - 1) * layout.page_size
        bio.seek(start)
        head = bio.read(8)
        if len(head) < 8 or head[0] != _TABLE_LEAF:
            continue
        (cells,) = struct.unpack_from(">H", head, 3)
        bio.seek(start + 8)
        pointers = bio.read(2 * cells)
        for index in range(len(pointers) // 2):
            (offset,) = struct.unpack_from(">H", pointers, 2 * index)
            if not 8 <= offset < layout.usable:
                continue
            row = _read_cell(bio, layout, start + offset, with_data=False)
            if isinstance(row, _Row):
                # A rowid seen twice (only with free pages past the cut): the first stays.
                rows.setdefault(row.rowid, row)
    return rows


def _read_cell(
    bio: IO[bytes], layout: Db3Layout, cell: int, with_data: bool
) -> "_Row | bytes | None":
    """Parse a table-leaf cell as a ``messages`` row; None when not one or not whole.

    Returns the row (``with_data=False``, overflow chain checked) or its
    ``data`` bytes (``with_data=True``).
    """
    bio.seek(cell)
    head = bio.read(18)
    payload_size, used = _varint(head, 0)
    rowid, used = _varint(head, used)
    if used > len(head):
        return None
    local = _local_size(layout.usable, payload_size)
    in_page = local + (4 if local < payload_size else 0)
    if cell % layout.page_size + used + in_page > layout.usable:  # not a cell of this page
        return None
    bio.seek(cell + used)
    first = bio.read(in_page)
    if len(first) < in_page:
        return None
    record = _message_record(first[:local], payload_size, rowid)
    if record is None:
        return None
    topic_id, log_time, data_start = record
    pieces = [first[:local]] if with_data else []
    left = payload_size - local
    page = struct.unpack_from(">L", first, local)[0] if left else 0
    step = layout.usable - 4
    while left:
        if not 2 <= page <= (layout.size - 1) // layout.page_size + 1:
            return None
        bio.seek((page - 1) * layout.page_size)
        piece_size = min(step, left)
        if with_data:
            block = bio.read(4 + piece_size)
            pieces.append(block[4:])
        else:  # the scan checks that the piece is there without reading it
            block = bio.read(4)
            if (page - 1) * layout.page_size + 4 + piece_size > layout.size:
                return None
        if len(block) < 4 or (with_data and len(block) < 4 + piece_size):
            return None
        (page,) = struct.unpack_from(">L", block)
        left -= piece_size
    if with_data:
        return b"".join(pieces)[data_start:]
    return _Row(rowid, topic_id, log_time, cell, payload_size - data_start)


def _local_size(usable: int, payload_size: int) -> int:
    """Payload bytes kept in a table-leaf cell (SQLite file format, section 1.6)."""
    most = usable - 35
    if payload_size <= most:
        return payload_size
    least = (usable - 12) * 32 // 255 - 23
    local = least + (payload_size - least) % (usable - 4)
    return local if local <= most else least


def _message_record(local: bytes, payload_size: int, rowid: int) -> tuple[int, int, int] | None:
    """``(topic_id, timestamp, data offset)`` of a ``messages`` record, else None.

    The record must be ``(id, topic_id, timestamp, data)``: ``id`` NULL (the
    rowid alias) or the rowid, two integers, and a blob ending the payload.
    """
    header_size, pos = _varint(local, 0)
    types: list[int] = []
    while pos < min(header_size, len(local)) and len(types) < 5:
        kind, pos = _varint(local, pos)
        types.append(kind)
    if pos != header_size or len(types) != 4 or header_size > len(local):
        return None
    if types[0] not in (0, *_INTEGER_TYPES) or types[1] not in _INTEGER_TYPES:
        return None
    if types[2] not in _INTEGER_TYPES or types[3] < 12 or types[3] % 2:
        return None
    values: list[int | None] = []
    for kind in types[:3]:
        width = _INTEGER_SIZES[kind]
        if pos + width > len(local):
            return None
        raw = local[pos : pos + width]
        value = kind - 8 if kind in (8, 9) else int.from_bytes(raw, "big", signed=True)
        values.append(None if kind == 0 else value)
        pos += width
    if values[0] is not None and values[0] != rowid:
        return None
    if pos + (types[3] - 12) // 2 != payload_size:
        return None
    assert values[1] is not None and values[2] is not None
    return values[1], values[2], pos


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    """SQLite varint at ``pos``: ``(value, position after it)``; past the end when cut."""
    value = 0
    for index in range(9):
        if pos + index >= len(data):
            return value, len(data) + 1
        byte = data[pos + index]
        if index == 8:
            return (value << 8) | byte, pos + 9
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, pos + index + 1
    raise AssertionError("unreachable")


def _free_pages(bio: IO[bytes], layout: Db3Layout, head: bytes) -> set[int]:
    """Pages on the free list that lie before the cut (trunk and leaf pages)."""
    free: set[int] = set()
    (trunk,) = struct.unpack_from(">L", head, 32)
    while trunk and trunk not in free:
        bio.seek((trunk - 1) * layout.page_size)
        block = bio.read(8)
        if len(block) < 8:
            break
        free.add(trunk)
        following, count = struct.unpack(">LL", block)
        listed = bio.read(4 * count)
        free.update(struct.unpack(f">{len(listed) // 4}L", listed[: len(listed) // 4 * 4]))
        trunk = following
    return free


def _db3_connections(
    bag: "SalvagedBag", bio: IO[bytes], pages: int, page_size: int
) -> dict[int, Connection]:
    """The ``topics`` rows (with ``message_definitions``), through SQLite on the whole pages."""
    handle, name = tempfile.mkstemp(suffix=".db3", prefix="lenspair-salvage-")
    try:
        with os.fdopen(handle, "wb") as out:  # whole pages only, streamed
            bio.seek(0)
            left = pages * page_size
            while left:
                block = bio.read(min(left, 1 << 20))
                if not block:  # the file shrank while being read
                    break
                out.write(block)
                left -= len(block)
            out.seek(28)  # the header's page count: SQLite stops at the last page
            out.write(struct.pack(">L", pages))
        db = sqlite3.connect(f"file:{name}?immutable=1", uri=True)
        try:
            return _topics(bag, db)
        finally:
            db.close()
    finally:
        os.unlink(name)


def _topics(bag: "SalvagedBag", db: sqlite3.Connection) -> dict[int, Connection]:
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
        bag.add_connection(connection)
    return known
