"""The camera's response: gain, sensor noise, sRGB encoding, one quantisation."""

import numpy as np

from lenspair.core.imageio import from_float, from_linear, to_float, to_linear


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
