import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lenspair.core.errors import ImageIOError
from lenspair.core.fsutil import sha256_file
from lenspair.core.imageio import read_alpha, read_image
from lenspair.core.imagewrite import write_image
from lenspair.core.pixels import from_float, from_linear, to_float, to_linear
from tests.images import texture


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("shape", [(37, 53), (37, 53, 3)])
@pytest.mark.parametrize("ext", [".png", ".tif"])
def test_write_read_round_trip_is_lossless(
    tmp_path: Path, dtype: type, shape: tuple[int, ...], ext: str
) -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, np.iinfo(dtype).max, size=shape, endpoint=True).astype(dtype)
    path = tmp_path / f"img{ext}"
    write_image(path, image)
    back = read_image(path)
    assert back.dtype == image.dtype
    np.testing.assert_array_equal(back, image)


def test_same_pixels_give_same_bytes(tmp_path: Path) -> None:
    image = (np.arange(540 * 720) % 65536).astype(np.uint16).reshape(540, 720)
    write_image(tmp_path / "a.png", image)
    write_image(tmp_path / "b.png", image.copy())
    assert sha256_file(tmp_path / "a.png") == sha256_file(tmp_path / "b.png")
    assert not list(tmp_path.glob(".*tmp"))  # no temporary files left behind


def test_truncated_and_missing_files_name_the_file(tmp_path: Path) -> None:
    good = tmp_path / "good.png"
    write_image(good, np.full((64, 64), 7, np.uint8) + np.eye(64, dtype=np.uint8))
    bad = tmp_path / "bad.png"
    bad.write_bytes(good.read_bytes()[: len(good.read_bytes()) // 2])
    with pytest.raises(ImageIOError, match=r"bad\.png: "):
        read_image(bad)
    with pytest.raises(ImageIOError, match=r"nope\.png: file not found"):
        read_image(tmp_path / "nope.png")
    (tmp_path / "text.png").write_text("not an image")
    with pytest.raises(ImageIOError, match=r"text\.png: "):
        read_image(tmp_path / "text.png")


def test_a_jpeg_cut_short_is_an_error_not_an_image_with_grey_rows(tmp_path: Path) -> None:
    """libjpeg decodes what it has and says the rest is missing: the rows came back grey."""
    rng = np.random.default_rng(0)
    whole = tmp_path / "whole.jpg"
    write_image(whole, (rng.random((96, 128, 3)) * 255).astype(np.uint8))
    assert read_image(whole).shape == (96, 128, 3)
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    with pytest.raises(ImageIOError, match=r"cut\.jpg: corrupt or truncated \(.*Premature end"):
        read_image(cut)
    # the right length, zeros from the middle to the end marker: libjpeg says "Corrupt JPEG
    # data: premature end of data segment" of this frame (of others, where zeros decode as
    # valid codes, it says nothing, and nothing can tell)
    noise = (np.random.default_rng(0).random((360, 480)) * 255).astype(np.uint8)
    smooth = cv2.normalize(cv2.GaussianBlur(noise, (0, 0), 3), None, 0, 255, cv2.NORM_MINMAX)
    data = bytearray(cv2.imencode(".jpg", smooth)[1].tobytes())
    data[len(data) // 2 : -2] = bytes(len(data) - 2 - len(data) // 2)
    (tmp_path / "zeros.jpg").write_bytes(bytes(data))
    said = r"zeros\.jpg: corrupt or truncated \(.*Corrupt JPEG data: premature end of data segment"
    with pytest.raises(ImageIOError, match=said):
        read_image(tmp_path / "zeros.jpg")
    # libjpeg's warnings about whole files are not errors: three stray bytes before a
    # marker, an unknown JFIF revision; the pixels are those of the intact file
    data = whole.read_bytes()
    stray = data.index(b"\xff\xdb")
    (tmp_path / "stray.jpg").write_bytes(data[:stray] + b"\x00\x01\x02" + data[stray:])
    jfif = data.index(b"JFIF\x00") + 5
    (tmp_path / "rev.jpg").write_bytes(data[:jfif] + b"\x02\x01" + data[jfif + 2 :])
    for name in ("stray.jpg", "rev.jpg"):
        np.testing.assert_array_equal(read_image(tmp_path / name), read_image(whole))


def _natural(shape: tuple[int, int]) -> np.ndarray:
    """A colour image with detail at every scale, as a camera frame has (8-bit)."""
    channels = [texture(shape, seed) for seed in range(3)]
    return (np.stack(channels, axis=2) * 255).astype(np.uint8)


def test_jpeg_quality_sets_a_jpegs_quality_by_its_format_not_its_suffix(tmp_path: Path) -> None:
    # restore wrote JPEGs at OpenImageIO's default (about 98): a quality-80 input came
    # back about 1.8 times larger
    image = _natural((120, 160))
    sizes = {}
    for quality, name in ((50, "low.JPEG"), (95, "high.jpg"), (None, "default.jpg")):
        write_image(tmp_path / name, image, jpeg_quality=quality)
        sizes[quality] = (tmp_path / name).stat().st_size
    assert sizes[50] < 0.6 * sizes[95] and sizes[95] < sizes[None], sizes
    low = read_image(tmp_path / "low.JPEG").astype(float)
    assert 0 < np.abs(low - image).mean() < 10  # the same picture, at a lower quality
    with pytest.raises(ValueError, match="outside 1-100"):
        write_image(tmp_path / "bad.jpg", image, jpeg_quality=0)


@pytest.mark.parametrize("ext", [".png", ".tif"])
def test_jpeg_quality_leaves_other_formats_lossless(tmp_path: Path, ext: str) -> None:
    """A TIFF told "jpeg:Q" as its Compression would have been lossy JPEG-in-TIFF."""
    image = _natural((60, 80))
    write_image(tmp_path / f"q{ext}", image, jpeg_quality=10)
    write_image(tmp_path / f"plain{ext}", image)
    np.testing.assert_array_equal(read_image(tmp_path / f"q{ext}"), image)
    assert (tmp_path / f"q{ext}").read_bytes() == (tmp_path / f"plain{ext}").read_bytes()


def test_write_rejects_float_images(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="expected dtype uint8 or uint16"):
        write_image(tmp_path / "f.png", np.zeros((4, 4), np.float32))


@given(st.floats(0.0, 1.0, width=32))
def test_srgb_linear_round_trip(value: float) -> None:
    x = np.array([value], np.float32)
    assert abs(float(from_linear(to_linear(x))[0]) - value) < 1e-5


def test_float_conversion_is_exact_for_every_code() -> None:
    codes = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    np.testing.assert_array_equal(from_float(to_float(codes), np.uint16), codes)
    assert from_float(np.array([[np.nan, -1.0, 2.0]], np.float32), np.uint8).tolist() == [
        [0, 0, 255]
    ]


@pytest.mark.parametrize(
    "damage", ["empty", "truncated", "flipped-byte", "no-iend", "garbage-after-signature"]
)
def test_damaged_png_is_one_clear_error_and_nothing_on_stderr(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], damage: str
) -> None:
    good = tmp_path / "good.png"
    rng = np.random.default_rng(0)
    write_image(good, (rng.random((48, 64)) * 255).astype(np.uint8))
    data = bytearray(good.read_bytes())
    bad = tmp_path / "bad.png"
    expected = {
        "empty": "empty file",
        "truncated": "truncated",
        "flipped-byte": "CRC mismatch",
        "no-iend": "truncated",
        # it said "truncated (chunk  is  at byte 8 cut off)": garbage read as a chunk
        "garbage-after-signature": r"corrupt \(no chunk type at byte 12: b' is '\)",
    }[damage]
    if damage == "empty":
        data = bytearray()
    elif damage == "truncated":
        data = data[: len(data) // 2]
    elif damage == "flipped-byte":
        data[len(data) // 2] ^= 0xFF
    elif damage == "garbage-after-signature":
        data = data[:8] + bytearray(b"this is garbage")
    else:
        data = data[:-12]
    bad.write_bytes(bytes(data))
    capfd.readouterr()
    with pytest.raises(ImageIOError, match=expected) as info:
        read_image(bad)
    assert str(info.value).startswith(f"{bad}: ")
    assert capfd.readouterr().err == ""  # libpng printed nothing


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_translucent_pixels_read_as_stored_and_alpha_round_trips(
    tmp_path: Path, dtype: type
) -> None:
    # OpenImageIO premultiplies a PNG's colour by its alpha unless told not to:
    # colour 200 at alpha 100 (8 bit) read as 78, darkening what the networks saw.
    top = np.iinfo(dtype).max
    colour = np.full((4, 5, 3), top * 200 // 255, dtype)
    alpha = np.full((4, 5), top * 100 // 255, dtype)
    alpha[0, 0] = 0  # fully transparent: its colour is kept too
    path = tmp_path / "rgba.png"
    write_image(path, colour, alpha=alpha)
    np.testing.assert_array_equal(read_image(path), colour)
    np.testing.assert_array_equal(read_alpha(path), alpha)
    write_image(tmp_path / "rgb.png", colour)
    assert read_alpha(tmp_path / "rgb.png") is None
    with pytest.raises(ValueError, match="alpha"):
        write_image(tmp_path / "bad.png", colour, alpha=alpha[:2])


def _write_channels(path: Path, names: tuple[str, ...], alpha: int) -> None:
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(4, 3, len(names), "uint8")
    spec.channelnames = names
    spec.alpha_channel = alpha
    output = oiio.ImageOutput.create(str(path))
    assert output.open(str(path), spec)
    output.write_image(np.arange(12 * len(names), dtype=np.uint8).reshape(3, 4, len(names)))
    output.close()


@pytest.mark.parametrize(
    ("names", "alpha"),
    [(("R", "G", "B", "A", "extra"), 3), (("R", "G", "B", "NIR"), -1), (("R", "G"), -1)],
)
def test_channels_that_would_be_lost_or_turned_into_alpha_are_an_error(
    tmp_path: Path, names: tuple[str, ...], alpha: int
) -> None:
    path = tmp_path / "multi.tif"
    _write_channels(path, names, alpha)
    # a TIFF names its extra channels channelN
    message = re.escape(f"{path}: {len(names)} channels (") + r"[^)]*\); lenspair reads grey, RGB"
    for reader in (read_image, read_alpha):
        with pytest.raises(ImageIOError, match=message):
            reader(path)


def test_rgba_and_grey_alpha_tiffs_still_read(tmp_path: Path) -> None:
    for names in (("R", "G", "B", "A"), ("Y", "A")):
        path = tmp_path / f"{len(names)}.tif"
        _write_channels(path, names, len(names) - 1)
        assert read_image(path).ndim == (3 if len(names) == 4 else 2)
        alpha = read_alpha(path)
        assert alpha is not None and alpha[0, 0] == len(names) - 1


@pytest.mark.parametrize(
    ("damage", "expected"),
    [
        ("short", r"truncated \(chunk IHDR at byte 8 cut off\)"),
        ("garbage", r"corrupt \(no chunk type at byte 12"),
        ("crc", "chunk IHDR at byte 8: CRC mismatch"),
    ],
)
def test_a_header_read_of_a_damaged_png_is_one_error_and_nothing_on_stderr(
    tmp_path: Path, capfd: pytest.CaptureFixture[str], damage: str, expected: str
) -> None:
    """Only reading pixels checked a PNG first: a header read (bit depth sampling, size
    checks) let libpng print "libpng error: ... hit end of file" above lenspair's line."""
    from lenspair.core.imageio import image_header

    good = tmp_path / "good.png"
    write_image(good, np.zeros((16, 24), np.uint16))
    data = bytearray(good.read_bytes())
    if damage == "short":
        data = data[:20]
    elif damage == "garbage":
        data = data[:8] + bytearray(b"this is garbage")
    else:
        data[20] ^= 0xFF  # inside IHDR's width
    bad = tmp_path / "bad.png"
    bad.write_bytes(bytes(data))
    capfd.readouterr()
    with pytest.raises(ImageIOError, match=expected) as info:
        image_header(bad)
    assert str(info.value).startswith(f"{bad}: ")
    assert capfd.readouterr().err == ""
    # a sound file's header costs no more than its first bytes and reads as before
    assert image_header(good) == (16, 24, 1, "uint16")


def test_an_image_too_large_for_memory_is_that_files_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """OpenImageIO's std::bad_alloc came out as a MemoryError that ended restore's reader
    thread, and the run with it, where one file's error was due."""
    from lenspair.core import imageio

    image = tmp_path / "huge.png"
    write_image(image, np.zeros((16, 24), np.uint8))

    def bad_alloc(path: Path, *args: bool) -> np.ndarray:
        raise MemoryError("std::bad_alloc")

    monkeypatch.setattr(imageio, "_read_pixels", bad_alloc)
    with pytest.raises(ImageIOError, match=r"huge.png: too large to read into memory \(24x16\)$"):
        read_image(image)


def test_a_tiff_of_several_pages_reads_its_first_and_says_so_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    # a camera SDK's stack of frames in one TIFF gave its first frame, the rest lost unsaid
    import OpenImageIO as oiio  # only this test writes a file of several pages

    from lenspair.core import imageio

    monkeypatch.setattr(imageio, "_SAID", set())
    pages = [np.full((6, 8), value, np.uint8) for value in (10, 20, 30)]
    spec = oiio.ImageSpec(8, 6, 1, "uint8")
    for name in ("a.tif", "b.tif"):
        output = oiio.ImageOutput.create(str(tmp_path / name))
        assert output.open(str(tmp_path / name), [spec] * 3)
        for index, page in enumerate(pages):
            if index:
                assert output.open(str(tmp_path / name), spec, "AppendSubimage")
            assert output.write_image(page[..., None])
        output.close()
    write_image(tmp_path / "single.tif", pages[1])
    with caplog.at_level("WARNING", logger="lenspair.core.imageio"):
        np.testing.assert_array_equal(read_image(tmp_path / "single.tif"), pages[1])
        assert caplog.messages == []
        for name in ("a.tif", "b.tif"):
            np.testing.assert_array_equal(read_image(tmp_path / name), pages[0])
    assert caplog.messages == [
        f"{tmp_path / 'a.tif'}: a TIFF of several images (pages): only the first is read (so "
        "for every such file); save one frame a file to use the others"
    ]
