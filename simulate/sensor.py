"""The camera's response: gain, the glass, sensor noise, sRGB encoding, one clip."""

from collections.abc import Callable

import numpy as np

from lenspair.core.pixels import from_float, from_linear


def expose(
    linear: np.ndarray,
    gain: float,
    noise_std: float,
    rng: np.random.Generator | None,
    dtype: type[np.uint8] | type[np.uint16],
) -> np.ndarray:
    """Turn rendered scene light into the integer image the camera writes.

    Args:
        linear: ``(H, W)`` or ``(H, W, 3)`` float32 linear light, ``>= 0``
            (full scale is 1 after ``gain``; what lies above it saturates).
        gain: exposure times gain, applied in linear light.
        noise_std: standard deviation of additive Gaussian noise in linear
            light (0 = none; ``rng`` is then not used).
        rng: generator for the noise.
        dtype: ``np.uint8`` or ``np.uint16``.

    Returns:
        sRGB-encoded ``dtype`` image of the same shape; values are clipped and
        rounded once, here.

    """
    values = linear * np.float32(gain)
    if noise_std > 0:
        if rng is None:
            raise ValueError("noise_std > 0 needs a random generator")
        noise = rng.standard_normal(values.shape, dtype=np.float32)
        values = values + noise * np.float32(noise_std)
    return from_float(from_linear(values), dtype)


Glass = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""Linear light -> (the light through the glass, its footprint mask).

The light is ``float32`` ``(H, W)`` or ``(H, W, C)`` at the sensor's scale
(exposure and gain applied) and not clipped: full scale is 1, a lamp may be
4. The glass returns light of the same shape, unchanged outside its footprint
(:func:`lenspair.simulate.render.apply_glass_linear`).
"""


def expose_through_glass(
    linear: np.ndarray,
    gain: float,
    noise_std: float,
    seed: np.random.SeedSequence,
    dtype: type,
    glass: Glass | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The clear view, the view through ``glass`` and its footprint, of one exposure.

    The glass acts on the light as it reaches the sensor: exposed, unclipped
    and without noise. Light over full scale stays over it while drops refract
    and blur it (a defocused drop over a lamp or a sunlit sky blooms to
    saturation, as on a real lens), and the sensor then adds its noise and
    clips and quantises once, as :func:`expose` does for the clear view. The
    noise is the clear view's own draw (a generator from ``seed``), so drops
    do not refract or blur it (a cue no real camera gives a network), and
    where the glass changed no light the obstructed view is the clear view,
    bit for bit.

    Returns:
        ``(clear, obstructed, mask)``; ``mask`` is 0 everywhere without glass.
    """
    clear = expose(linear, gain, noise_std, np.random.default_rng(seed), dtype)
    if glass is None:
        return clear, clear, np.zeros(clear.shape[:2], dtype=np.uint8)
    glassed, mask = glass(linear * np.float32(gain))
    rng = np.random.default_rng(seed) if noise_std > 0 else None
    return clear, expose(glassed, 1.0, noise_std, rng, dtype), mask
