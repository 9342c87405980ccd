"""The camera's response: gain, sensor noise, sRGB encoding, one quantisation."""

from collections.abc import Callable

import numpy as np

from lenspair.core.pixels import from_float, from_linear, to_float, to_linear


def expose(
    linear: np.ndarray,
    gain: float,
    noise_std: float,
    rng: np.random.Generator | None,
    dtype: type[np.uint8] | type[np.uint16],
) -> np.ndarray:
    """Turn rendered scene light into the integer image the camera writes.

    Args:
        linear: ``(H, W)`` or ``(H, W, 3)`` float32 linear light, ``[0, 1]``.
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


def add_noise(
    encoded: np.ndarray, noise_std: float, rng: np.random.Generator, dtype: type
) -> np.ndarray:
    """Add :func:`expose`'s sensor noise to an image already encoded (in linear light).

    For light that reached the sensor through the glass: the sensor adds its
    noise after the glass, so the drops must not refract or blur it. With
    the generator :func:`expose` drew the clear view's noise from, the draw
    is the same pixel for pixel.
    """
    values = to_linear(to_float(encoded))
    noise = rng.standard_normal(values.shape, dtype=np.float32)
    return from_float(from_linear(values + noise * np.float32(noise_std)), dtype)


Glass = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""Encoded image -> (the image through the glass, its footprint mask)."""


def expose_through_glass(
    linear: np.ndarray,
    gain: float,
    noise_std: float,
    seed: np.random.SeedSequence,
    dtype: type,
    glass: Glass | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The clear view, the view through ``glass`` and its footprint, of one exposure.

    The sensor adds its noise behind the glass: the glass acts on the
    noiseless exposure and the clear view's own noise draw (a generator from
    ``seed``) is added to what it changed (drops had refracted and blurred
    the noise away, a cue no real camera gives a network). Where the glass
    changed nothing the clear view stands as exposed, and light it leaves
    saturated stays saturated: noise added again to a clipped, quantised
    pixel drew the footprint in saturated light. Without noise the glass acts
    on the clear view itself.

    Returns:
        ``(clear, obstructed, mask)``; ``mask`` is 0 everywhere without glass.
    """
    clear = expose(linear, gain, noise_std, np.random.default_rng(seed), dtype)
    if glass is None:
        return clear, clear, np.zeros(clear.shape[:2], dtype=np.uint8)
    if noise_std == 0:
        obstructed, mask = glass(clear)
        return clear, obstructed, mask
    bare = expose(linear, gain, 0.0, None, dtype)
    glassed, mask = glass(bare)
    noisy = add_noise(glassed, noise_std, np.random.default_rng(seed), dtype)
    noisy = np.where(glassed == np.iinfo(dtype).max, glassed, noisy)
    return clear, np.where(glassed != bare, noisy, clear), mask
