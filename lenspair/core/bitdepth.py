"""16-bit frames that hold 10- or 12-bit values, as machine-vision cameras send them.

A Mono10 or Mono12 sensor's driver often publishes ``mono16`` words holding
the values as they come (0..1023, 0..4095). Read as 16-bit data they are all
but black: quality checks call them blank or blurred, registration finds no
corners, the network sees a black frame. :func:`significant_bits` tells the
depth from the values, :func:`widen` scales to the full 16-bit range and
:func:`narrow` back (``narrow(widen(v)) == v`` for every value of the depth).
"""

import logging
import threading

import numpy as np

from lenspair.core.numbers import is_whole_number

log = logging.getLogger(__name__)

LOW_BIT_DEPTHS = (10, 12)
"""Depths of machine-vision cameras whose drivers publish 16-bit words with the value in
the low bits (``mono16`` from a Mono10/Mono12 sensor): :func:`significant_bits`.

14 is left out on purpose: a 14-bit camera's values (below 16384) cannot be
told from a genuine 16-bit frame of a dim scene (brightest pixel under a
quarter of the range, common at dusk), which would be brightened fourfold;
below 4096 (12 bits) a genuine 16-bit frame is nearly black."""


BIT_DEPTHS = (*LOW_BIT_DEPTHS, 16)
"""The depths a caller may name for 16-bit frames (``bits=``)."""


def is_bit_depth(bits: object) -> bool:
    """Whether ``bits`` is one of :data:`BIT_DEPTHS` as a whole number.

    ``12.0 == 12``: a float passed a plain membership test and failed at the
    first frame's shift; ``True == 1`` is no depth either.
    """
    return is_whole_number(bits) and bits in BIT_DEPTHS


def significant_bits(images: list[np.ndarray]) -> int:
    """The bits that 16-bit frames really use: 10, 12, or 16.

    10 or 12 when no value of ``images`` (frames sampled over a recording, or
    one frame) exceeds that depth's largest value, else 16; 8-bit frames (or
    none): 16, meaning "as they are". A genuine 16-bit frame whose brightest
    pixel is below 4096 (6 % of the range) is nearly black, and is brightened
    too; the callers say so.
    """
    wide = [image for image in images if image.dtype == np.uint16]
    if not wide or len(wide) != len(images):
        return 16
    top = max(int(image.max()) for image in wide)
    return next((bits for bits in LOW_BIT_DEPTHS if top < 1 << bits), 16)


def widen(image: np.ndarray, bits: int) -> np.ndarray:
    """A ``uint16`` image of ``bits``-bit values on the full 16-bit scale; others as they are.

    The bits are replicated into the low end (``4095 -> 65535``, ``0 -> 0``),
    so full scale stays full scale (the saturation check looks for it); a
    value above ``bits`` (a frame the sample missed) saturates.
    """
    if bits >= 16 or image.dtype != np.uint16:
        return image
    shift = 16 - bits
    values = np.minimum(image, np.uint16((1 << bits) - 1))
    return np.asarray((values << shift) | (values >> (bits - shift)), dtype=np.uint16)


def narrow(image: np.ndarray, bits: int) -> np.ndarray:
    """A full-range ``uint16`` image back to ``bits``-bit values (rounded); others as they are.

    The inverse of :func:`widen` (exact on its outputs); a restored frame goes
    back into the words its camera wrote.
    """
    if bits >= 16 or image.dtype != np.uint16:
        return image
    top = (1 << bits) - 1
    values = np.rint(image.astype(np.float64) * (top / 65535.0))
    return np.asarray(np.clip(values, 0, top), dtype=np.uint16)


class RunningDepth:
    """The bits an input's 16-bit frames use, told from the frames seen so far.

    ``restore`` and ``detect`` take frames one by one and cannot sample ahead
    as ``capture-ingest`` does: the depth is the least of 10, 12 and 16 that
    holds every frame seen so far. It only ever rises, so a dim frame of a
    12-bit camera never switches the gain back and forth. Logged (a warning
    naming ``source``) when it is first below 16 and when it rises from there.
    """

    def __init__(self, source: str) -> None:
        """Nothing seen yet: :attr:`bits` is 16 until a frame says otherwise."""
        self.source = source
        self._bits = 0
        # two camera callbacks share one Restorer: a check-then-set without it could
        # lower the depth (12 written after 16), which must only rise
        self._lock = threading.Lock()

    @property
    def bits(self) -> int:
        """The depth to :func:`widen` and :func:`narrow` with (16: frames as they are)."""
        return self._bits or 16

    def rise(self, image: np.ndarray) -> int | None:
        """:meth:`see` ``image``; the depth before it when it raised it, else ``None``.

        A batch being gathered is then run at that earlier depth first: a
        frame must not rescale the frames before it (restore, detect alike).
        """
        before = self.bits
        self.see(image)
        return before if self.bits != before else None

    def see(self, image: np.ndarray) -> None:
        """Take one more frame into account (an 8-bit one tells nothing of 16-bit ones)."""
        if image.dtype != np.uint16:
            return  # it would read as 16 bits, which never drops again
        bits = significant_bits([image])
        if bits == LOW_BIT_DEPTHS[0] and not image.any():  # only dark frames pay this pass
            return  # a black frame (a node's warm-up call) holds no value to tell a depth by
        with self._lock:
            if bits <= self._bits:
                return
            before, self._bits = self._bits, bits
        if bits < 16:
            log.warning(
                "%s: its 16-bit frames hold %d-bit values (none above %d so far): taken on "
                "the full 16-bit scale",
                self.source,
                bits,
                (1 << bits) - 1,
            )
        elif before:
            log.warning(
                "%s: a frame holds values above %d: 16-bit frames are taken as they are from "
                "here on",
                self.source,
                (1 << before) - 1,
            )
