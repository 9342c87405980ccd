"""Brightened drops: some drops look brighter than the scene behind them.

On real rigs a drop often catches light from a bright part of the scene (the
sky, a lamp) and glows. The paper mimics this by brightening a random subset
of drops; here each drop is brightened with probability ``fraction`` by a
gain drawn from ``gain``, applied to its colour in linear light. Gains above
1 may push values past white: they are clipped once, at the end of rendering.
"""

import numpy as np

from lenspair.simulate.effects.spec import BrightnessSpec


def sample_gains(spec: BrightnessSpec, count: int, rng: np.random.Generator) -> np.ndarray:
    """Per-drop gains: 1 for untouched drops, ``U(gain)`` for brightened ones.

    Args:
        spec: the brightness spec.
        count: number of drops.
        rng: random generator.

    Returns:
        ``float32`` ``(count,)`` gains >= 0.

    """
    chosen = rng.random(count) < spec.fraction
    gains = rng.uniform(*spec.gain, count)
    return np.where(chosen, gains, 1.0).astype(np.float32)


def brighten(colour: np.ndarray, owner: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """Multiply each drop pixel's linear colour by its drop's gain.

    Args:
        colour: ``float32`` ``(M, C)`` linear colours of the drop pixels.
        owner: ``int64`` ``(M,)`` drop index of each pixel.
        gains: ``float32`` ``(N,)`` per-drop gains.

    Returns:
        ``float32`` ``(M, C)`` brightened colours (may exceed 1).

    """
    result: np.ndarray = (colour * gains.astype(np.float32)[owner][:, None]).astype(np.float32)
    return result
