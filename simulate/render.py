"""Renderer API (contract stub; the effects helper replaces the bodies).

``render_effects(image, effects, rng, hook=None) -> (obstructed, mask)``
works on any clean image. For recordings, ``sample_glass`` draws the glass
state once (drops stay put while the robot drives) and ``apply_glass``
renders it onto each frame.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from simulate.effects.spec import EffectsSpec

EffectHook = Callable[[str], None]
"""Called with an effect's name each time that effect is computed (instrumentation)."""


@dataclass(frozen=True)
class GlassState:
    """Everything sampled about the glass for one frame size (drops, blobs, dust fields)."""

    effects: EffectsSpec
    shape: tuple[int, int]


def sample_glass(
    effects: EffectsSpec, shape: tuple[int, int], rng: np.random.Generator
) -> GlassState:
    """Sample the glass state for images of ``shape`` = (H, W)."""
    raise NotImplementedError


def apply_glass(
    image: np.ndarray, glass: GlassState, hook: EffectHook | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Render ``glass`` over a clean image; returns (obstructed, mask)."""
    raise NotImplementedError


def render_effects(
    image: np.ndarray,
    effects: EffectsSpec,
    rng: np.random.Generator,
    hook: EffectHook | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Render ``effects`` over a clean image (sample + apply in one call)."""
    return apply_glass(image, sample_glass(effects, image.shape[:2], rng), hook)
