"""Image files read through OpenImageIO: their pixels, alpha, and what their headers say.

Pixels come back in the convention of :mod:`lenspair.core.pixels` (``uint8``
or ``uint16``, ``(H, W)`` or ``(H, W, 3)``, as stored); files are written by
:mod:`lenspair.core.imagewrite`, which takes back what a header says here
(orientation, alpha, descriptive attributes) when an image replaces a file.
"""

import contextlib
import logging
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import OpenImageIO as oiio

from lenspair.core.errors import ImageIOError, first_text_line
from lenspair.core.pngcheck import HEADER_BYTES, png_header_problem, png_problem

logger = logging.getLogger(__name__)

_UNKNOWN = "unknown error"  # an OpenImageIO failure that gives no reason
TIFF_SUFFIXES = frozenset({".tif", ".tiff"})


def read_image(path: Path, *, say_pages: bool = True) -> np.ndarray:
    """Read an 8- or 16-bit image file (PNG, TIFF, ...).

    Returns:
        ``uint8``/``uint16`` array, ``(H, W)`` for one channel, ``(H, W, 3)``
        for colour, as stored (an alpha channel is dropped, see :func:`read_alpha`;
        colour is not premultiplied by it). A TIFF of several pages gives its
        first, and with ``say_pages`` the first such file is named in a warning
        (``restore``, which copies such a file whole and lists it, says it its way).

    Raises:
        ImageIOError: the file is missing, empty, corrupt or truncated (a PNG's
            chunks are checked first, so libpng prints nothing), unreadable
            (permissions, I/O error), too large for memory, or has a pixel
            format other than 8/16-bit integer; the message names it.

    """
    path = Path(path)
    if not path.is_file():
        raise ImageIOError(f"{path}: file not found")
    try:
        array = _read_pixels(path, say_pages)
    except OSError as exc:  # permissions, I/O errors: this file only
        raise ImageIOError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    except MemoryError:  # OpenImageIO's std::bad_alloc: this file only, said with its size
        size = _header_size(path)
        raise ImageIOError(f"{path}: too large to read into memory{size}") from None
    channels = array.shape[2]
    if channels in (1, 2):  # mono, or mono + alpha
        return np.ascontiguousarray(array[:, :, 0])
    return np.ascontiguousarray(array[:, :, :3])


def _header_size(path: Path) -> str:
    """`` (WxH)`` from ``path``'s header, or "" when even that cannot be read."""
    try:
        height, width = image_header(path)[:2]
    except (ImageIOError, MemoryError):
        return ""
    return f" ({width}x{height})"


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
        "oiio:ColorSpace", "oiio:Gamma",  # the same, by a PNG's gAMA (1.0: linear): not sRGB
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

FORMAT_TEXT = frozenset(
    {"compression", "planarconfig", "resolutionunit", "textureformat", "wrapmodes"}
)
"""OpenImageIO's own text attributes without a namespace (lower case): how the file was
stored (a JPEG-compressed TIFF's ``compression`` would make the new one lossy), not the
picture; other text without one is the file's own (a PNG's ``tEXt``: a timestamp, a comment)."""

DEFAULT_COLOUR_SPACES = frozenset({"srgb_rec709_scene", "srgb"})
"""``oiio:ColorSpace`` values (lower case) that say what OpenImageIO assumes of a file that
says nothing, and writes anyway: left out, or a JPEG would gain an EXIF block claiming sRGB."""

BITS_ATTRIBUTE = "oiio:BitsPerSample"
"""The bits a file stores per value: 10 or 12 in a machine-vision camera's TIFF, which
OpenImageIO reads on the 16-bit scale; kept where between 8 and 16 (:func:`image_metadata`)."""

Attribute = tuple[str, Any, Any]
"""An image attribute as OpenImageIO holds it: ``(name, TypeDesc, value)``."""


def image_metadata(path: Path) -> tuple[Attribute, ...]:
    """The descriptive attributes of a file's header: ICC profile, colour space, EXIF, GPS, IPTC.

    Whoever writes an image back in the file's place (``restore``) hands
    them to :func:`~lenspair.core.imagewrite.write_image`'s ``metadata``, or
    the new file loses its colour profile (a wide-gamut photo shown in sRGB),
    its colour space (a linear PNG, gAMA 1.0, tagged sRGB and shown brighter),
    its camera, its capture time and its text (a PNG's ``tEXt``, such as a
    timestamp). Attributes of the file's format and geometry (resolution,
    compression, the format's own ``png:``/``tiff:``/``oiio:`` ones and
    :data:`FORMAT_TEXT`, the ICC profile's decoded ``ICCProfile:`` fields) are
    left to the writer; so is ``Orientation`` (:func:`image_layout`). The bit
    depth is too, but for :data:`BITS_ATTRIBUTE` of a 16-bit image stored in
    fewer bits (a 12-bit TIFF), which the writer keeps where the format holds it.

    Raises:
        ImageIOError: as :func:`image_header`.
    """
    with _opened(Path(path)) as handle:
        spec = handle.spec()
        colours = spec.nchannels - (1 if spec.alpha_channel >= 0 else 0)
        kept = tuple(
            (item.name, item.type, item.value)
            for item in spec.extra_attribs
            if _kept(item.name, item.type, item.value)
            and not (item.name == "ICCProfile" and _foreign_profile(path, item.value, colours))
        )
        bits = int(spec.get_int_attribute(BITS_ATTRIBUTE, 16))
        if str(spec.format) == "uint16" and 8 < bits < 16:
            kept += ((BITS_ATTRIBUTE, oiio.TypeInt, bits),)
        return kept


ICC_SPACES = {1: b"GRAY", 3: b"RGB "}
"""The ICC colour space signature (header bytes 16-19) of grey and of RGB pixels."""


def _foreign_profile(path: Path, profile: Any, colours: int) -> bool:
    """Whether an ICC profile describes other colours than the pixels read (said once a space).

    OpenImageIO reads a CMYK JPEG or TIFF as RGB: its CMYK profile, written on
    the RGB image in the file's place, made colour-managed viewers reject the
    file or misread every colour.
    """
    space = bytes(np.asarray(profile, dtype=np.uint8)[16:20].tobytes())
    if space == ICC_SPACES.get(colours):
        return False
    said = space.decode("ascii", "replace").strip() or "unknown"
    _say_once(
        f"profile {said}",
        "%s: its ICC profile is for %s colours, and the image is read as %s: the profile "
        "is left out of the image written in its place (so for every such file)",
        path,
        said,
        "grey" if colours == 1 else "RGB",
    )
    return True


def _kept(name: str, kind: Any, value: Any) -> bool:
    """Whether :func:`image_metadata` keeps the attribute ``name`` (of type ``kind``, ``value``)."""
    if name in GEOMETRY_ATTRIBUTES:
        return False
    if name == "oiio:ColorSpace" and str(value).lower() in DEFAULT_COLOUR_SPACES:
        return False
    if name in KEPT_ATTRIBUTES or name.startswith(KEPT_PREFIXES):
        return True
    return kind == oiio.TypeString and ":" not in name and name.lower() not in FORMAT_TEXT


def read_alpha(path: Path) -> np.ndarray | None:
    """The alpha channel of an image file, ``(H, W)`` of its dtype; ``None`` when it has none.

    :func:`read_image` drops alpha (the networks see colour only); whoever
    writes an image back in the file's place (``restore``) puts it back with
    :func:`~lenspair.core.imagewrite.write_image`'s ``alpha``. Only the header
    is read when there is none.

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
    if path.suffix.lower() not in TIFF_SUFFIXES:
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
    if path.suffix.lower() == ".png":  # libpng prints its own line on a damaged header
        problem = _png_header_problem(path)
        if problem is not None:
            raise ImageIOError(f"{path}: {problem}")
    handle = oiio.ImageInput.open(oiio_name(path), config)
    if handle is None:
        raise ImageIOError(
            f"{path}: cannot open image ({first_text_line(oiio.geterror(), _UNKNOWN)})"
        )
    try:
        yield handle
    finally:
        handle.close()


def _png_header_problem(path: Path) -> str | None:
    """:func:`~lenspair.core.pngcheck.png_header_problem` of ``path``'s first bytes.

    A file that cannot be read here (missing, no permission) is left to
    OpenImageIO, which names the reason as it always has.
    """
    try:
        with path.open("rb") as file:
            head = file.read(HEADER_BYTES)
    except OSError:
        return None
    return png_header_problem(head)


READABLE_FORMATS = frozenset({"uint8", "uint16"})
"""Pixel formats :func:`read_image` reads (as :func:`image_header` names them)."""


def format_problem(kind: str) -> str:
    """Why :func:`read_image` refuses pixels of format ``kind`` ("" when it reads them)."""
    return "" if kind in READABLE_FORMATS else f"unsupported pixel format {kind} (need 8/16-bit)"


def _pixels_lost(error: str) -> bool:
    """Whether libjpeg's words (through OpenImageIO) say rows were made up.

    A file cut short ("Premature end of JPEG file") or whose data segment
    ends early, as an interrupted copy leaves it with zeros to its end marker
    ("Corrupt JPEG data: premature end of data segment"), or holds a bad
    Huffman code or a misplaced marker ("Corrupt JPEG data: ..."), decodes
    with its missing rows grey or smeared. Stray bytes before a marker
    ("Corrupt JPEG data: 3 extraneous bytes before marker") and an unknown
    JFIF revision are said of files whose pixels are whole: those are read.
    """
    said = error.lower()
    if "premature end" in said:
        return True
    return "corrupt jpeg data" in said and "extraneous bytes" not in said


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


def _read_pixels(path: Path, say_pages: bool = False) -> np.ndarray:
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
        # a damaged JPEG decodes, its missing rows made up: only libjpeg's words tell
        if pixels is None or _pixels_lost(error):
            raise ImageIOError(f"{path}: corrupt or truncated ({first_text_line(error, _UNKNOWN)})")
        if say_pages and path.suffix.lower() in TIFF_SUFFIXES and handle.seek_subimage(1, 0):
            _say_once(
                "pages",
                "%s: a TIFF of several images (pages): only the first is read (so for every "
                "such file); save one frame a file to use the others",
                path,
            )
    return np.asarray(pixels)


def _say_once(kind: str, message: str, *args: object) -> None:
    """Log ``message`` as a warning the first time a file shows ``kind`` in this process."""
    if kind not in _SAID:
        _SAID.add(kind)
        logger.warning(message, *args)


_SAID: set[str] = set()
