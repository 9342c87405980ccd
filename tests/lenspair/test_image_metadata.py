"""What a restored image keeps of its file's header: colour space, text, a 10/12-bit depth.

``restore`` writes each image in its file's place with
:func:`~lenspair.core.imageio.image_metadata`; a network that changes nothing
shows what the writing alone keeps.
"""

import struct
import zlib
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from lenspair.core.bitdepth import widen
from lenspair.core.imageio import image_metadata, read_image
from lenspair.core.imagewrite import write_image
from lenspair.model.inference.pipeline import restore_input
from lenspair.model.inference.restore_options import RestoreOptions


class _Unchanged:
    """A network that returns its input: every pixel is written back as it was read."""

    fixed_size = None
    forced_tiles = None
    description = "unchanged"

    def __init__(self, channels: int) -> None:
        self.channels = channels

    def __call__(self, batch: np.ndarray) -> np.ndarray:
        return batch


def _write(path: Path, pixels: np.ndarray, **attributes: object) -> Path:
    """``pixels`` ``(H, W, C)`` written by OpenImageIO with ``attributes``, as other tools do."""
    height, width, channels = pixels.shape
    spec = oiio.ImageSpec(
        width, height, channels, "uint16" if pixels.dtype == np.uint16 else "uint8"
    )
    for name, value in attributes.items():
        spec.attribute(name.replace("__", ":"), value)
    path.parent.mkdir(parents=True, exist_ok=True)
    out = oiio.ImageOutput.create(str(path))
    assert (
        out is not None
        and out.open(str(path), spec)
        and out.write_image(np.ascontiguousarray(pixels))
    )
    out.close()
    return path


def _png_chunks(path: Path) -> list[tuple[str, bytes]]:
    data, at, chunks = path.read_bytes(), 8, []
    while at < len(data):
        (length,) = struct.unpack(">I", data[at : at + 4])
        chunks.append((data[at + 4 : at + 8].decode("ascii"), data[at + 8 : at + 8 + length]))
        at += 12 + length
    return chunks


def _tiff_tags(path: Path) -> dict[int, list[int]]:
    """The SHORT and LONG tags of a little-endian TIFF's first image that :func:`_tiff_samples`
    reads: width, bits per sample, compression, strips, predictor."""
    data = path.read_bytes()
    assert data[:4] == b"II*\x00"
    (ifd,) = struct.unpack("<I", data[4:8])
    (count,) = struct.unpack("<H", data[ifd : ifd + 2])
    tags: dict[int, list[int]] = {}
    for index in range(count):
        entry = ifd + 2 + 12 * index
        tag, kind, number, value = struct.unpack("<HHII", data[entry : entry + 12])
        if tag not in (256, 258, 259, 273, 279, 317):
            continue
        size = {3: 2, 4: 4}[kind]  # SHORT or LONG
        raw = data[entry + 8 :][: number * size] if number * size <= 4 else data[value:]
        tags[tag] = list(
            struct.unpack(f"<{number}{'H' if size == 2 else 'I'}", raw[: number * size])
        )
    return tags


def _tiff_samples(path: Path) -> tuple[int, np.ndarray]:
    """``(bits per sample, the stored values)`` of a one-channel strip TIFF, read from its bytes.

    OpenImageIO reads a 12-bit file on the 16-bit scale, so the stored values are
    unpacked here (uncompressed or zip, no predictor: what OpenImageIO writes at 12 bits).
    """
    tags = _tiff_tags(path)
    width, bits, compression = tags[256][0], tags[258][0], tags[259][0]
    assert bits == 12, f"{path.name}: {bits} bits per sample"
    assert tags.get(317, [1]) == [1] and compression in (1, 8, 32946)
    data = path.read_bytes()
    strips = [data[start : start + size] for start, size in zip(tags[273], tags[279], strict=True)]
    stored = b"".join(zlib.decompress(s) if compression != 1 else s for s in strips)
    row_bytes = (width * bits + 7) // 8
    rows = np.frombuffer(stored, np.uint8).reshape(-1, row_bytes)
    bit_rows = np.unpackbits(rows, axis=1)[:, : width * bits].reshape(len(rows), width, bits)
    weights = 1 << np.arange(bits - 1, -1, -1, dtype=np.int64)
    return bits, (bit_rows.astype(np.int64) * weights).sum(axis=2)


@pytest.mark.parametrize(
    ("colour_space", "gamma", "stored_gamma"),
    [("lin_rec709_scene", None, 100000), ("g20_rec709_scene", 2.0, 50000)],
)
def test_a_png_keeps_its_gamma_through_restore(
    tmp_path: Path, colour_space: str, gamma: float | None, stored_gamma: int
) -> None:
    """A linear PNG (gAMA 1.0) came back tagged sRGB (gAMA 0.45455): viewers showed it brighter."""
    attributes: dict[str, object] = {"oiio__ColorSpace": colour_space}
    if gamma is not None:
        attributes["oiio__Gamma"] = gamma
    pixels = np.random.default_rng(0).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    source = _write(tmp_path / "in" / "frame.png", pixels, **attributes)
    assert ("gAMA", struct.pack(">I", stored_gamma)) in _png_chunks(source)
    report = restore_input(source.parent, tmp_path / "out", _Unchanged(3), RestoreOptions())
    assert report.restored == 1
    chunks = _png_chunks(tmp_path / "out" / "frame.png")
    assert ("gAMA", struct.pack(">I", stored_gamma)) in chunks
    assert "sRGB" not in [kind for kind, _ in chunks]
    np.testing.assert_array_equal(read_image(tmp_path / "out" / "frame.png"), pixels)


def test_a_png_keeps_its_text_through_restore(tmp_path: Path) -> None:
    """Its tEXt chunks but Description (kept as ImageDescription) were dropped."""
    pixels = np.random.default_rng(3).integers(0, 256, (24, 32), dtype=np.uint8)[:, :, None]
    text = {"timestamp": "1700000000.123", "Comment": "lens 2", "ImageDescription": "left"}
    source = _write(tmp_path / "in" / "frame.png", pixels, **text)
    report = restore_input(source.parent, tmp_path / "out", _Unchanged(1), RestoreOptions())
    assert report.restored == 1
    chunks = _png_chunks(tmp_path / "out" / "frame.png")
    texts = dict(body.split(b"\0", 1) for kind, body in chunks if kind == "tEXt")
    assert texts == {
        b"timestamp": b"1700000000.123",
        b"Comment": b"lens 2",
        b"Description": b"left",
    }


def test_a_12_bit_tiff_is_restored_as_a_12_bit_tiff_of_the_same_values(tmp_path: Path) -> None:
    """It came back a 16-bit TIFF, every value rescaled (0..4095 stored as 0..65535)."""
    stored = (np.arange(40 * 48, dtype=np.int64).reshape(40, 48) * 7) % 4096
    pixels = widen(stored.astype(np.uint16), 12)[:, :, None]  # OpenImageIO stores the top bits
    source = _write(tmp_path / "in" / "mono12.tif", pixels, oiio__BitsPerSample=12)
    bits, values = _tiff_samples(source)
    assert bits == 12 and np.array_equal(values, stored)
    report = restore_input(source.parent, tmp_path / "out", _Unchanged(1), RestoreOptions())
    assert report.restored == 1
    restored = tmp_path / "out" / "mono12.tif"
    bits, values = _tiff_samples(restored)
    assert bits == 12 and np.array_equal(values, stored)
    written = oiio.ImageInput.open(str(restored))
    assert written is not None and written.spec().get_int_attribute("oiio:BitsPerSample") == 12
    written.close()


def test_a_12_bit_tiff_stores_each_restored_value_rounded_to_12_bits(tmp_path: Path) -> None:
    """OpenImageIO keeps a value's top 12 bits, which is one below the nearest for many."""
    source = _write(tmp_path / "in.tif", np.zeros((8, 8, 1), np.uint16), oiio__BitsPerSample=12)
    values = np.random.default_rng(1).integers(0, 65536, (30, 40), dtype=np.uint16)
    write_image(tmp_path / "out.tif", values, metadata=image_metadata(source))
    bits, stored = _tiff_samples(tmp_path / "out.tif")
    assert bits == 12
    np.testing.assert_array_equal(stored, np.rint(values.astype(np.float64) * 4095 / 65535))


def test_what_describes_the_old_file_is_not_carried(tmp_path: Path) -> None:
    """How the file was stored (compression, layout, depth of an 8-bit or 1-bit file, the
    resolution's unit) and OpenImageIO's own sRGB guess are the writer's to decide."""
    pixels = np.random.default_rng(2).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    tiff = _write(
        tmp_path / "j.tif", pixels, compression="jpeg", ResolutionUnit="in", XResolution=300.0
    )
    kept = {name: value for name, _, value in image_metadata(tiff)}
    assert not {"compression", "planarconfig", "ResolutionUnit", "oiio:BitsPerSample"} & set(kept)
    write_image(tmp_path / "out.tif", pixels, metadata=image_metadata(tiff))
    written = oiio.ImageInput.open(str(tmp_path / "out.tif"))
    assert (
        written is not None and written.spec().get_string_attribute("compression") != "jpeg"
    )  # not made lossy
    written.close()
    plain = _write(tmp_path / "plain.png", pixels)
    assert image_metadata(plain) == ()  # no colour chunk: OpenImageIO's sRGB guess, not kept
    one_bit = _write(tmp_path / "one.png", pixels[:, :, :1] // 255 * 255, oiio__BitsPerSample=1)
    assert "oiio:BitsPerSample" not in {name for name, _, _ in image_metadata(one_bit)}


def test_a_tiff_gets_no_time_of_writing_and_keeps_the_time_it_was_given(tmp_path: Path) -> None:
    # OpenImageIO stamped each TIFF with the time it wrote it: a tag the input lacked, and a
    # resumed restore differed from an uninterrupted one in those bytes
    pixels = np.random.default_rng(4).integers(0, 256, (16, 16), dtype=np.uint8)
    write_image(tmp_path / "a.tif", pixels)
    assert "DateTime" not in {name for name, _, _ in image_metadata(tmp_path / "a.tif")}
    given = (("DateTime", oiio.TypeDesc("string"), "2024:05:01 12:00:00"),)
    write_image(tmp_path / "b.tif", pixels, metadata=given)
    assert ("DateTime", "2024:05:01 12:00:00") in {
        (name, value) for name, _, value in image_metadata(tmp_path / "b.tif")
    }


def test_a_12_bit_tiff_misnamed_png_comes_out_a_16_bit_png(tmp_path: Path) -> None:
    """PNG holds no 12 bits (OpenImageIO writes 16 then): its values stay on the 16-bit scale."""
    stored = np.arange(64, dtype=np.uint16).reshape(8, 8) * 60
    source = _write(tmp_path / "x.tif", widen(stored, 12)[:, :, None], oiio__BitsPerSample=12)
    read = read_image(source)
    write_image(tmp_path / "x.png", read, metadata=image_metadata(source))
    np.testing.assert_array_equal(read_image(tmp_path / "x.png"), read)
