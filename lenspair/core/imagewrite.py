"""Image files written through OpenImageIO, atomically, and checked once written.

OpenImageIO's Python binding misreads 2-D arrays on write (rows come out
strided and the bytes differ from run to run), so every write goes through
an explicit ``(H, W, C)`` contiguous array; the output bytes are then a pure
function of the pixels. Images follow :mod:`lenspair.core.pixels`; reading
is :mod:`lenspair.core.imageio`.
"""

import errno
import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from lenspair.core.bitdepth import narrow, widen
from lenspair.core.errors import ImageIOError, first_text_line
from lenspair.core.fsutil import atomic_write
from lenspair.core.imageio import BITS_ATTRIBUTE, Attribute, oiio_name
from lenspair.core.pixels import check_image
from lenspair.core.pngcheck import png_problem

_UNKNOWN = "unknown error"  # an OpenImageIO failure that gives no reason
_OIIO_TYPES = {np.dtype(np.uint8): oiio.UINT8, np.dtype(np.uint16): oiio.UINT16}


FAST_PNG = 1
"""zlib level for PNGs written where throughput matters (``restore``): on
natural 540x360 frames about twice as fast to write as the default level 6,
for files a few per cent larger (the same pixels)."""

DEPTH_FORMATS = frozenset({"tiff"})
"""Formats OpenImageIO writes in the ``oiio:BitsPerSample`` of a 16-bit image (a 12-bit
TIFF); elsewhere (a 12-bit TIFF misnamed ``.png``) it is written in 16 bits."""


def write_image(
    path: Path,
    image: np.ndarray,
    png_level: int | None = None,
    alpha: np.ndarray | None = None,
    orientation: int = 1,
    associated: bool = False,
    metadata: Sequence[Attribute] = (),
    jpeg_quality: int | None = None,
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
            after the colour ones (grey + alpha, RGBA); see
            :func:`~lenspair.core.imageio.read_alpha`.
        orientation: the EXIF/TIFF ``Orientation`` to record (1, as stored: none
            is written); see :func:`~lenspair.core.imageio.image_layout`.
        associated: ``alpha`` is associated (the colour is premultiplied, as
            in the TIFF it came from:
            :func:`~lenspair.core.imageio.alpha_is_associated`), and a TIFF
            says so; the colour is written as given either way.
        metadata: descriptive attributes to record (ICC profile, EXIF, as
            the format holds them); see :func:`~lenspair.core.imageio.image_metadata`.
            Its ``oiio:BitsPerSample`` (10 or 12) stores a 16-bit image in those
            bits where the format holds them (:data:`DEPTH_FORMATS`): the file
            reads back on the 16-bit scale, as the one it replaces did.
        jpeg_quality: JPEG quality 1-100 (``None``: the library's default, about
            98) when the file is a JPEG, by the format OpenImageIO picks for
            its extension; ignored for every other format (given to a TIFF,
            ``jpeg:Q`` would ask for lossy JPEG-in-TIFF).

    Raises:
        ValueError: ``jpeg_quality`` outside 1-100.

    """
    if jpeg_quality is not None and not 1 <= jpeg_quality <= 100:
        raise ValueError(f"{path}: JPEG quality {jpeg_quality} is outside 1-100")
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
        out = oiio.ImageOutput.create(oiio_name(path))
        bits = _stored_bits(metadata, image.dtype, out)
        spec = oiio.ImageSpec(width, height, channels, _OIIO_TYPES[image.dtype])
        for name, kind, value in metadata:
            if name != BITS_ATTRIBUTE or bits is not None:
                spec.attribute(name, kind, value)
        if not any(name == "DateTime" for name, _, _ in metadata):
            # else a TIFF gets the time of writing (OpenImageIO's default): a tag its input lacked,
            # and bytes that differ between a resumed run and an uninterrupted one
            spec.attribute("DateTime", "")
        if alpha is not None:
            spec.alpha_channel = channels - 1
            if not associated:  # colour as given, not divided by alpha
                spec.attribute("oiio:UnassociatedAlpha", 1)
        if png_level is not None:
            spec.attribute("png:compressionLevel", png_level)
        if orientation != 1:
            spec.attribute("Orientation", orientation)
        # by the format OpenImageIO writes, not the suffix: "Compression" means another
        # thing to other formats (jpeg:Q asks a TIFF for lossy JPEG-in-TIFF)
        if out is not None and jpeg_quality is not None and out.format_name() == "jpeg":
            spec.attribute("Compression", f"jpeg:{jpeg_quality}")
        if out is None or not out.open(oiio_name(tmp), spec):
            why = out.geterror() if out is not None else ""
            raise ImageIOError(
                f"{path}: cannot write ({first_text_line(why or oiio.geterror(), _UNKNOWN)})"
            )
        lost = _format_loses(out, spec, alpha is not None)
        if lost:
            out.close()
            raise ImageIOError(f"{path}: cannot write: {lost}")
        ok = out.write_image(pixels if bits is None else widen(narrow(pixels, bits), bits))
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


def _stored_bits(
    metadata: Sequence[Attribute], dtype: np.dtype, out: "oiio.ImageOutput | None"
) -> int | None:
    """The bits a 16-bit image is stored in, by ``metadata``'s ``oiio:BitsPerSample``; None: all.

    OpenImageIO stores the top bits of each 16-bit value, one code below the
    nearest for many of them: :func:`~lenspair.core.bitdepth.narrow`
    rounds the values to the depth and :func:`~lenspair.core.bitdepth.widen`
    puts them back on the 16-bit scale, whose top bits are the rounded value
    (an unchanged pixel of a 12-bit file is stored as it was).
    """
    bits = next((int(value) for name, _, value in metadata if name == BITS_ATTRIBUTE), 16)
    if dtype != np.uint16 or not 8 < bits < 16 or out is None:
        return None
    return bits if out.format_name() in DEPTH_FORMATS else None


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
