"""Image files through OpenImageIO, and the pixel conventions of lenspair.

Conventions (stated once, checked where data enters):

* **On disk / in arrays between stages**: ``uint8`` or ``uint16``, shape
  ``(H, W)`` for mono or ``(H, W, 3)`` for RGB, sRGB-encoded as cameras and
  PNG viewers expect. Bit depth is preserved end to end.
* **Inside renderers and metrics**: ``float32`` in ``[0, 1]``; blending
  happens in *linear* light (:func:`to_linear` / :func:`from_linear`).

OpenImageIO's Python binding misreads 2-D arrays on write (rows come out
strided and the bytes differ from run to run), so every write goes through
an explicit ``(H, W, C)`` contiguous array; the output bytes are then a pure
function of the pixels.
"""

import contextlib
import errno
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import OpenImageIO as oiio

from lenspair.core.errors import ImageIOError, first_text_line
from lenspair.core.fsutil import atomic_write
from lenspair.core.pngcheck import png_problem

_UNKNOWN = "unknown error"  # an OpenImageIO failure that gives no reason
_OIIO_TYPES = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16}


def check_image(image: np.ndarray, name: str = "image") -> None:
    """Raise ``ValueError`` unless ``image`` is uint8/uint16 (H, W) or (H, W, 3), H, W >= 1."""
    if image.dtype not in _OIIO_TYPES:
        raise ValueError(f"{name}: expected dtype uint8 or uint16, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise ValueError(f"{name}: expected shape (H, W) or (H, W, 3), got {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"{name}: an empty image, shape {image.shape}")


def read_image(path: Path) -> np.ndarray:
    """Read an 8- or 16-bit image file (PNG, TIFF, ...).

    Returns:
        ``uint8``/``uint16`` array, ``(H, W)`` for one channel, ``(H, W, 3)``
        for colour, as stored (an alpha channel is dropped, see :func:`read_alpha`;
        colour is not premultiplied by it).

    Raises:
        ImageIOError: the file is missing, empty, corrupt or truncated (a PNG's
            chunks are checked first, so libpng prints nothing), unreadable
            (permissions, I/O error), or has a pixel format other than
            8/16-bit integer; the message names it.

    """
    path = Path(path)
    if not path.is_file():
        raise ImageIOError(f"{path}: file not found")
    try:
        array = _read_pixels(path)
    except OSError as exc:  # permissions, I/O errors: this file only
        raise ImageIOError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    channels = array.shape[2]
    if channels in (1, 2):  # mono, or mono + alpha
        return np.ascontiguousarray(array[:, :, 0])
    return np.ascontiguousarray(array[:, :, :3])


def image_header(path: Path) -> tuple[int, int, int, str]:
    """``(height, width, channels, format)`` from a file's header, pixels unread.

    ``channels`` counts as :func:`read_image` returns them (1 or 3: alpha
    dropped), so two files whose headers agree read to arrays of one shape.

    Raises:
        ImageIOError: the file is missing or its header unreadable (names it).
    """
    with _opened(Path(path)) as handle:
        spec = handle.spec()
        channels = 1 if spec.nchannels in (1, 2) else 3
        return spec.height, spec.width, channels, str(spec.format)


def image_layout(path: Path) -> tuple[int, int]:
    """``(orientation, pages)`` from a file's header.

    The EXIF/TIFF ``Orientation`` (1 when none: as stored), and how many images
    the file holds (a multi-page TIFF holds several; counted up to 2).

    Whoever writes an image back in the file's place (``restore``) keeps the
    orientation, or viewers turn the new file by 90 degrees against the old one.

    Raises:
        ImageIOError: as :func:`image_header`.
    """
    with _opened(Path(path)) as handle:
        orientation = int(handle.spec().get_int_attribute("Orientation", 1))
        pages = 1
        while pages < 2 and handle.seek_subimage(pages, 0):
            pages += 1
    return orientation, pages


KEPT_ATTRIBUTES = frozenset(
    {
        "ICCProfile",  # what the colour values mean: without it, viewers take them as sRGB
        "Make", "Model", "Software", "DateTime", "ImageDescription", "Artist", "Copyright",
        "DocumentName", "HostComputer", "Keywords", "ExposureTime", "FNumber",
    }
)  # fmt: skip
"""Descriptive attributes (OpenImageIO's names) an image written in a file's place keeps."""

KEPT_PREFIXES = ("Exif:", "GPS:", "IPTC:")
"""Attribute groups kept too: the camera's EXIF (capture time, exposure), position, captions."""

GEOMETRY_ATTRIBUTES = frozenset(
    {"Exif:PixelXDimension", "Exif:PixelYDimension", "Exif:CompressedBitsPerPixel"}
)
"""EXIF tags that describe the file's encoding, not the picture: the writer decides them."""

Attribute = tuple[str, Any, Any]
"""An image attribute as OpenImageIO holds it: ``(name, TypeDesc, value)``."""


def image_metadata(path: Path) -> tuple[Attribute, ...]:
    """The descriptive attributes of a file's header: ICC profile, EXIF, GPS, IPTC.

    Whoever writes an image back in the file's place (``restore``) hands
    them to :func:`write_image`'s ``metadata``, or the new file loses its
    colour profile (a wide-gamut photo shown in sRGB), its camera and its
    capture time. Attributes of the file's format and geometry (resolution,
    compression, bit depth, the format's own ``png:``/``tiff:``/``oiio:``
    ones, the ICC profile's decoded ``ICCProfile:`` fields) are left to the
    writer; so is ``Orientation`` (:func:`image_layout`).

    Raises:
        ImageIOError: as :func:`image_header`.
    """
    with _opened(Path(path)) as handle:
        return tuple(
            (item.name, item.type, item.value)
            for item in handle.spec().extra_attribs
            if (item.name in KEPT_ATTRIBUTES or item.name.startswith(KEPT_PREFIXES))
            and item.name not in GEOMETRY_ATTRIBUTES
        )


def read_alpha(path: Path) -> np.ndarray | None:
    """The alpha channel of an image file, ``(H, W)`` of its dtype; ``None`` when it has none.

    :func:`read_image` drops alpha (the networks see colour only); whoever
    writes an image back in the file's place (``restore``) puts it back with
    :func:`write_image`'s ``alpha``. Only the header is read when there is none.

    Raises:
        ImageIOError: as :func:`read_image`.
    """
    path = Path(path)
    with _opened(path) as handle:
        spec = handle.spec()
        if problem := _channel_problem(spec.nchannels, spec.alpha_channel, spec.channelnames):
            raise ImageIOError(f"{path}: {problem}")
        if spec.nchannels not in (2, 4):
            return None
    try:
        array = _read_pixels(path)
    except OSError as exc:
        raise ImageIOError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    return np.ascontiguousarray(array[:, :, -1])


def alpha_is_associated(path: Path) -> bool:
    """Whether a TIFF's alpha is associated (colour stored premultiplied); header only.

    TIFF says which (``ExtraSamples``); OpenImageIO reports an unassociated
    one as ``oiio:UnassociatedAlpha``. Other formats (PNG) are unassociated
    by definition: ``False``, as for a file without alpha.

    Raises:
        ImageIOError: as :func:`read_image`.
    """
    path = Path(path)
    if path.suffix.lower() not in (".tif", ".tiff"):
        return False
    with _opened(path) as handle:
        spec = handle.spec()
        unassociated = int(spec.get_int_attribute("oiio:UnassociatedAlpha", 0)) == 1
        return int(spec.alpha_channel) >= 0 and not unassociated


def oiio_name(path: Path) -> str:
    """``path`` as OpenImageIO takes it: text that encodes as UTF-8.

    A file name of other bytes (a Latin-1 name from an old camera, a damaged
    card) reaches Python as surrogate escapes, and OpenImageIO's binding
    refused it with a ``TypeError`` traceback that stopped the whole run.

    Raises:
        ImageIOError: the name is not UTF-8 (this file only).
    """
    text = str(path)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        shown = text.encode("utf-8", "backslashreplace").decode("ascii", "backslashreplace")
        raise ImageIOError(
            f"{shown}: the file name is not UTF-8, which OpenImageIO cannot open; rename it"
        ) from None
    return text


@contextlib.contextmanager
def _opened(path: Path) -> Iterator[Any]:
    """An OpenImageIO input for ``path``, closed on exit.

    Raises:
        ImageIOError: it cannot be opened (OpenImageIO's reason).
    """
    # The stored colour values: by default OpenImageIO premultiplies a PNG's
    # colour by its alpha (200 at alpha 100 reads as 78), darkening every
    # translucent pixel of what the networks and metrics see.
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    handle = oiio.ImageInput.open(oiio_name(path), config)
    if handle is None:
        raise ImageIOError(
            f"{path}: cannot open image ({first_text_line(oiio.geterror(), _UNKNOWN)})"
        )
    try:
        yield handle
    finally:
        handle.close()


READABLE_FORMATS = frozenset({"uint8", "uint16"})
"""Pixel formats :func:`read_image` reads (as :func:`image_header` names them)."""


def format_problem(kind: str) -> str:
    """Why :func:`read_image` refuses pixels of format ``kind`` ("" when it reads them)."""
    return "" if kind in READABLE_FORMATS else f"unsupported pixel format {kind} (need 8/16-bit)"


_CUT_SHORT = "Premature end"
"""How libjpeg (through OpenImageIO) says a file ended before its image did."""


def _channel_problem(channels: int, alpha: int, names: Sequence[str]) -> str | None:
    """Why lenspair cannot read these channels without losing one, or None.

    It reads grey and RGB, each with or without alpha as the last channel. A
    fifth channel, or a last channel the file does not call alpha (an RGB +
    near-infrared TIFF), would be dropped, or written back as transparency.
    """
    if channels in (1, 3) or (channels in (2, 4) and alpha == channels - 1):
        return None
    what = "grey, RGB, and either with alpha as the last channel"
    return f"{channels} channels ({', '.join(names)}); lenspair reads {what}"


def _read_pixels(path: Path) -> np.ndarray:
    """The pixels of an existing file as OpenImageIO returns them, ``(H, W, C)``."""
    if path.stat().st_size == 0:
        raise ImageIOError(f"{path}: empty file (0 bytes)")
    if path.suffix.lower() == ".png":  # keeps libpng's own stderr lines away
        problem = png_problem(path.read_bytes())
        if problem is not None:
            raise ImageIOError(f"{path}: {problem}")
    with _opened(path) as handle:
        spec = handle.spec()
        problem = format_problem(str(spec.format)) or _channel_problem(
            spec.nchannels, spec.alpha_channel, spec.channelnames
        )
        if problem:
            raise ImageIOError(f"{path}: {problem}")
        pixels = handle.read_image(spec.format)
        error = handle.geterror()
        # A JPEG cut short decodes: its missing rows come back grey, and libjpeg says the
        # data ended. Its other complaints (extraneous bytes, an unknown JFIF revision)
        # are warnings about files whose pixels are whole: those are read.
        if pixels is None or _CUT_SHORT in error:
            raise ImageIOError(f"{path}: corrupt or truncated ({first_text_line(error, _UNKNOWN)})")
    return np.asarray(pixels)


FAST_PNG = 1
"""zlib level for PNGs written where throughput matters (``restore``): on
natural 540x360 frames about twice as fast to write as the default level 6,
for files a few per cent larger (the same pixels)."""


def write_image(
    path: Path,
    image: np.ndarray,
    png_level: int | None = None,
    alpha: np.ndarray | None = None,
    orientation: int = 1,
    associated: bool = False,
    metadata: Sequence[Attribute] = (),
) -> None:
    """Write ``image`` atomically; the format follows the file extension.

    Args:
        path: destination; any format OpenImageIO writes, by its extension
            (an image the format cannot hold, 16 bits or an alpha channel in
            a JPEG, is refused: see :func:`_format_loses`).
        image: ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)``.
        png_level: zlib compression level 0-9 of a PNG (``None``: the
            library's default); see :data:`FAST_PNG`.
        alpha: an alpha channel ``(H, W)`` of ``image``'s dtype to write
            after the colour ones (grey + alpha, RGBA); see :func:`read_alpha`.
        orientation: the EXIF/TIFF ``Orientation`` to record (1, as stored: none
            is written); see :func:`image_layout`.
        associated: ``alpha`` is associated (the colour is premultiplied, as
            in the TIFF it came from: :func:`alpha_is_associated`), and a TIFF
            says so; the colour is written as given either way.
        metadata: descriptive attributes to record (ICC profile, EXIF, as
            the format holds them); see :func:`image_metadata`.

    """
    check_image(image, str(path))
    pixels = np.ascontiguousarray(image if image.ndim == 3 else image[:, :, None])
    if alpha is not None:
        if alpha.shape != pixels.shape[:2] or alpha.dtype != image.dtype:
            raise ValueError(
                f"{path}: alpha {alpha.shape} {alpha.dtype} does not match the image "
                f"{pixels.shape[:2]} {image.dtype}"
            )
        pixels = np.ascontiguousarray(np.concatenate([pixels, alpha[:, :, None]], axis=2))
    height, width, channels = pixels.shape
    path = Path(path)

    def _write(tmp: Path) -> None:
        spec = oiio.ImageSpec(width, height, channels, _OIIO_TYPES[image.dtype])
        for name, kind, value in metadata:
            spec.attribute(name, kind, value)
        if alpha is not None:
            spec.alpha_channel = channels - 1
            if not associated:  # colour as given, not divided by alpha
                spec.attribute("oiio:UnassociatedAlpha", 1)
        if png_level is not None:
            spec.attribute("png:compressionLevel", png_level)
        if orientation != 1:
            spec.attribute("Orientation", orientation)
        out = oiio.ImageOutput.create(oiio_name(path))
        if out is None or not out.open(oiio_name(tmp), spec):
            why = out.geterror() if out is not None else ""
            raise ImageIOError(
                f"{path}: cannot write ({first_text_line(why or oiio.geterror(), _UNKNOWN)})"
            )
        lost = _format_loses(out, spec, alpha is not None)
        if lost:
            out.close()
            raise ImageIOError(f"{path}: cannot write: {lost}")
        ok = out.write_image(pixels)
        closed = out.close()
        error = out.geterror()  # not always a failure: TIFFs carry a note on their Exif data
        if not (ok and closed):
            raise _write_failure(path, tmp, error)
        # OpenImageIO answers True when the disk fills: its error text may say so, and a
        # write refused while closing (the last buffer) it does not report at all
        short = error if _SHORT_WRITE in error else ""
        problem = short or _written_problem(tmp, path.suffix)
        if problem:
            raise _write_failure(path, tmp, problem)

    atomic_write(path, _write, suffix=path.suffix, sync=False)  # frames: see atomic_write


def _format_loses(out: "oiio.ImageOutput", spec: "oiio.ImageSpec", alpha: bool) -> str:
    """What the file's format would drop of the image ("" if nothing).

    OpenImageIO writes what the format holds, silently: a JPEG takes 8-bit
    values only and no alpha, so a 16-bit or grey + alpha PNG misnamed
    ``.jpg`` came out 8-bit, or as a colour image of grey, alpha and zero.
    """
    name = out.format_name().upper()
    used = out.spec()
    if alpha and not out.supports("alpha"):
        return f"{name} holds no alpha channel"
    if used.nchannels != spec.nchannels:
        return f"{name} cannot hold {spec.nchannels} channels"
    if used.format != spec.format:
        return f"{name} holds {used.format} values, not the image's {spec.format}"
    return ""


_SHORT_WRITE = "Write error"
"""How OpenImageIO's error text starts for a write the file system cut short."""


def _written_problem(tmp: Path, suffix: str) -> str:
    """Why the file just written is not whole ("" when it is): the structure read back.

    A PNG's chunks are walked (:func:`~lenspair.core.pngcheck.png_problem`: lengths and
    CRCs, 0.06-0.5 ms for a 540x360 frame, from the page cache); other formats are
    decoded (TIFF: about 1 ms).
    """
    if suffix.lower() == ".png":  # the temporary's own suffix is .tmp
        problem = png_problem(tmp.read_bytes())
        return "" if problem is None else f"{_SHORT_WRITE}: the file written is {problem}"
    handle = oiio.ImageInput.open(str(tmp))
    if handle is None:
        why = oiio.geterror()
    else:
        why = "" if handle.read_image() is not None else handle.geterror() or "no pixels"
        handle.close()
    return (
        f"{_SHORT_WRITE}: the file written does not read back ({first_text_line(why)})"
        if why
        else ""
    )


def _write_failure(path: Path, tmp: Path, error: str) -> Exception:
    """The exception of a failed image write: the file system's refusal, or the library's error.

    A short write ("could only write N bytes") is the file system refusing
    (a full disk or quota): an ``OSError`` naming ``path``, which the CLI says
    in one line (exit 1). Either way the temporary is removed by
    :func:`~lenspair.core.fsutil.atomic_write` and nothing takes ``path``.
    """
    if _SHORT_WRITE in error:
        if shutil.disk_usage(tmp.parent).free < (1 << 20):
            return OSError(errno.ENOSPC, "No space left on device", str(path))
        # a quota or a file-size limit: OpenImageIO does not say which
        reason = "the file system cut the write short (a quota or file-size limit?)"
        return OSError(errno.EIO, reason, str(path))
    return ImageIOError(f"{path}: write failed ({first_text_line(error, 'no reason given')})")


def max_value(dtype: np.dtype | type) -> float:
    """Largest code value of an integer image dtype (255 or 65535)."""
    return float(np.iinfo(np.dtype(dtype)).max)


def to_float(image: np.ndarray) -> np.ndarray:
    """Integer image to ``float32`` in ``[0, 1]`` (still sRGB-encoded)."""
    check_image(image)
    return image.astype(np.float32) / np.float32(max_value(image.dtype))


def from_float(image: np.ndarray, dtype: np.dtype | type) -> np.ndarray:
    """``float32`` image in ``[0, 1]`` to integer codes, clipping once, rounding."""
    scale = np.float32(max_value(dtype))
    scaled = np.clip(np.nan_to_num(image, nan=0.0), 0.0, 1.0) * scale
    return np.asarray(np.rint(scaled).astype(dtype))


def to_linear(encoded: np.ndarray) -> np.ndarray:
    """sRGB-encoded ``[0, 1]`` float32 to linear light (IEC 61966-2-1)."""
    x = np.asarray(encoded, dtype=np.float32)
    low = x / np.float32(12.92)
    high = np.power((np.maximum(x, 0.04045) + np.float32(0.055)) / np.float32(1.055), 2.4)
    return np.where(x <= 0.04045, low, high).astype(np.float32)


def from_linear(linear: np.ndarray) -> np.ndarray:
    """Linear-light float32 to sRGB-encoded ``[0, 1]`` float32 (input clipped to >= 0)."""
    x = np.maximum(np.asarray(linear, dtype=np.float32), 0.0)
    low = x * np.float32(12.92)
    high = np.float32(1.055) * np.power(np.maximum(x, 0.0031308), 1 / 2.4) - np.float32(0.055)
    return np.where(x <= 0.0031308, low, high).astype(np.float32)
