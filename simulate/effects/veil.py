"""Veiling glare of wet glass: scattered light lowers contrast over the whole frame.

A film of water and many tiny droplets scatter a share ``s`` of the light
reaching each pixel over wide angles; the camera then sees, in linear light
and per channel, ``I = (1 - s) I0 + s V`` with the veil ``V = level *
mean(I0)`` (the scattered light is an average over the scene, brightened by
``level`` because bright parts of the scene, the sky above all, dominate it).
Contrast (the standard deviation in linear light) drops by exactly
``1 - s`` everywhere, inside and outside drops: what real wet-glass images
show and drops alone cannot (Raindrop pairs: ``std(obstructed) /
std(clean)`` of 0.68-0.90).
"""

from dataclasses import dataclass

import numpy as np

from lenspair.simulate.effects.spec import VeilSpec


@dataclass(frozen=True)
class Veil:
    """The veil of one glass state.

    Attributes:
        strength: scattered share ``s`` in ``[0, 1]``.
        level: veil brightness relative to the scene mean, >= 0.

    """

    strength: float
    level: float


def sample_veil(spec: VeilSpec, rng: np.random.Generator) -> Veil:
    """Draw the veil's strength and level uniformly from the spec's ranges."""
    return Veil(strength=float(rng.uniform(*spec.strength)), level=float(rng.uniform(*spec.level)))


def veil_light(linear: np.ndarray, veil: Veil) -> np.ndarray:
    """The veil ``V = level * mean(I0)`` per channel.

    Args:
        linear: ``float32`` ``(..., C)`` linear-light pixels of the whole frame.
        veil: the veil.

    Returns:
        ``float32`` ``(C,)`` veil light (may exceed 1; clipped once when encoded).

    """
    channels = linear.shape[-1]
    mean = linear.reshape(-1, channels).mean(axis=0, dtype=np.float64)
    light: np.ndarray = (veil.level * mean).astype(np.float32)
    return light


def apply_veil(values: np.ndarray, light: np.ndarray, strength: float) -> np.ndarray:
    """``(1 - s) * values + s * light`` in linear light.

    Args:
        values: ``float32`` ``(M, C)`` linear-light pixels.
        light: ``float32`` ``(C,)`` veil light from :func:`veil_light`.
        strength: scattered share ``s`` in ``[0, 1]``.

    Returns:
        ``float32`` ``(M, C)``; finite wherever the inputs are.

    """
    share = np.float32(strength)
    veiled: np.ndarray = ((1.0 - share) * values + share * light).astype(np.float32)
    return veiled
