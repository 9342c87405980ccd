"""The anomaly kinds a simulated recording is labelled with (``rig.yaml``'s ``anomaly``).

A declared effect earns its label only by what it did to the obstructed
frames: one whose sampled glass holds nothing (a Poisson draw of no dust
patch) or that changed no pixel of any frame (drops of a thousandth of a
pixel, dirt too faint to move a code) is left out with a warning, and the
rules of :attr:`~lenspair.simulate.effects.spec.EffectsSpec.anomaly_kinds`
apply to what is left. Whether one effect among several changed a pixel is
decided by rendering the frame without it (:func:`~lenspair.simulate.render.
without_effect`): only while it has not yet shown, so a visible effect costs
that once, on the first frame.
"""

import logging
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from lenspair.simulate.effects.layer import Sprites
from lenspair.simulate.effects.spec import EffectsSpec
from lenspair.simulate.render import GlassState, without_effect

log = logging.getLogger(__name__)

DRAWS_NOTHING = {
    "raindrops": "no drop covers a pixel; raise raindrops.radius_px",
    "dirt": "no blob covers a pixel; raise dirt.radius_px",
    "dust": "no patch was drawn; raise dust.coverage, lower dust.scale_px or change the seed",
    "veil": "its strength drew 0; raise veil.strength",
}
"""The effects whose sampled glass can hold nothing, and what to change then; they are
the effects labels follow (brightness and defocus act on the drops and the dirt)."""


def drawn(glass: GlassState) -> frozenset[str]:
    """The effects of :data:`DRAWS_NOTHING` that ``glass`` holds something of in the frame."""
    height, width = glass.shape

    def covers(sprites: Sprites | None) -> bool:
        if sprites is None:
            return False
        rows, cols = sprites.ys, sprites.xs
        return bool(((rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)).any())

    held = {
        "raindrops": glass.optics is not None and covers(glass.optics.sprites),
        "dirt": covers(glass.dirt),
        "dust": glass.dust is not None and bool(glass.dust.support.any()),
        "veil": glass.veiling is not None and glass.veiling.strength > 0,
    }
    return frozenset(name for name, holds in held.items() if holds)


class Seen:
    """What the obstructed frames rendered so far showed of each effect.

    Attributes:
        drawn: the effects the glass held something of in any frame.
        visible: the effects that changed a pixel of any frame.

    """

    def __init__(self) -> None:
        self.drawn: frozenset[str] = frozenset()
        self.visible: set[str] = set()
        self._glass: GlassState | None = None  # the glass `_held` was taken of
        self._held: frozenset[str] = frozenset()

    def note(
        self,
        glass: GlassState,
        clear: np.ndarray,
        image: np.ndarray,
        render_through: Callable[[GlassState], np.ndarray],
    ) -> None:
        """Take in one frame: its ``clear`` view and its ``image`` through ``glass``.

        ``render_through(other)`` renders the same exposure through another
        glass (the same noise), for an effect that shares the frame with others.
        """
        if glass is not self._glass:  # the same until drops move
            self._glass, self._held = glass, drawn(glass)
            self.drawn |= self._held
        unproven = self._held - self.visible
        if not unproven or np.array_equal(image, clear):
            return
        if len(self._held) == 1:
            self.visible |= unproven
            return
        for name in sorted(unproven):
            if not np.array_equal(image, render_through(without_effect(glass, name))):
                self.visible.add(name)


def labels(effects: EffectsSpec, seen: Seen, out_dir: Path) -> tuple[str, ...]:
    """rig.yaml's anomaly kinds: those of the declared effects the frames showed.

    The glass is sampled once per recording (dust, dirt, veil stay; drops, a
    fixed count, may be replaced between frames), and an effect counts if it
    showed in any frame, so one label holds for every frame.
    """
    missing = [name for name in effects.listed if name in DRAWS_NOTHING and name not in seen.drawn]
    for name in missing:
        log.warning(
            "%s: %s is declared but drew nothing on the glass (%s): rig.yaml omits it",
            out_dir,
            name,
            DRAWS_NOTHING[name],
        )
    faint = [name for name in effects.listed if name in seen.drawn - seen.visible]
    if faint:
        log.warning(
            "%s: the effects (%s) changed no pixel of any frame (too small or faint at this "
            "resolution and bit depth): rig.yaml omits them",
            out_dir,
            ", ".join(faint),
        )
    return replace(effects, **dict.fromkeys(missing + faint)).anomaly_kinds
