"""A PNG file's structure checked before decoding: one clear line, nothing on stderr.

libpng reports a damaged file by printing ``libpng error: ...`` straight to
the process's stderr before OpenImageIO or OpenCV return their own error,
which breaks progress bars and repeats what lenspair reports anyway.
:func:`png_problem` walks the chunks of a PNG file (signature, lengths,
CRC-32 of every chunk, ``IHDR`` first, ``IEND`` last), which finds the
truncated and corrupted files met in practice without decoding a pixel, so
that the decoder only sees files whose structure is sound. A corruption
inside the compressed data with matching CRCs still reaches the decoder
(and its error); that takes a deliberately forged file.
"""

import struct
import zlib

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_problem(data: bytes) -> str | None:
    """What is wrong with the structure of PNG bytes ``data``, or ``None``.

    Args:
        data: the whole file.

    Returns:
        One phrase (``empty file (0 bytes)``, ``not a PNG file``,
        ``truncated (no IEND chunk)``, ``chunk IDAT at byte 57: CRC mismatch``)
        or ``None`` when every chunk is intact.

    """
    if not data:
        return "empty file (0 bytes)"
    if not data.startswith(PNG_SIGNATURE):
        return "not a PNG file"
    position = len(PNG_SIGNATURE)
    first = True
    while position < len(data):
        if position + 8 > len(data):
            return f"truncated (chunk header at byte {position} cut off)"
        length, kind = struct.unpack(">I4s", data[position : position + 8])
        if not all(65 <= c <= 90 or 97 <= c <= 122 for c in kind):
            # chunk types are four ASCII letters: these bytes are damage, not a chunk
            return f"corrupt (no chunk type at byte {position + 4}: {bytes(kind)!r})"
        end = position + 12 + length
        name = kind.decode("ascii")
        if end > len(data):
            return f"truncated (chunk {name} at byte {position} cut off)"
        if first and kind != b"IHDR":
            return f"chunk {name} at byte {position}: expected IHDR first"
        (crc,) = struct.unpack(">I", data[end - 4 : end])
        if zlib.crc32(data[position + 4 : end - 4]) != crc:
            return f"chunk {name} at byte {position}: CRC mismatch (corrupt file)"
        if kind == b"IEND":
            return None
        first = False
        position = end
    return "truncated (no IEND chunk)"


HEADER_BYTES = len(PNG_SIGNATURE) + 12 + 13
"""The signature and the ``IHDR`` chunk (13 bytes of data): all a header read decodes."""


def png_header_problem(head: bytes) -> str | None:
    """What is wrong with a PNG's signature and ``IHDR`` chunk, or ``None``.

    Args:
        head: the file's first :data:`HEADER_BYTES` bytes (or all of a shorter file).

    Reading a header (size, channels, bit depth) decodes only these; checking
    them keeps libpng's stderr line away from a header read too, at the cost
    of 33 bytes rather than the whole file :func:`png_problem` reads.
    """
    problem = png_problem(head[:HEADER_BYTES])
    return None if problem == "truncated (no IEND chunk)" else problem
