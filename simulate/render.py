"""The anomaly renderer: what the glass in front of the obstructed camera does.

``render_effects(image, effects, rng, hook=None) -> (obstructed, mask)``
works on any clean image. For recordings, :func:`sample_glass` draws the
glass state once (drops stay put while the robot drives), :func:`apply_glass`
renders it onto each frame, and :func:`advance_glass` optionally replaces a
``1 - persistence`` share of the drops between frames.

Image convention: ``uint8``/``uint16``, ``(H, W)`` or ``(H, W, 3)``,
sRGB-encoded (see :mod:`lenspair.core.pixels`); the output has the input's
dtype and shape. Rendering happens in linear light in ``float32``; values
are clipped once, when encoded back.

Pipeline (only listed effects are computed, in ``EffectsSpec.listed`` order):
``raindrops`` (refracting drops) and ``brightness`` (gains on some drops)
and ``dirt`` (blobs) build a premultiplied *glass layer*; ``defocus`` blurs
that layer; it is composited over the clean image; ``dust`` then applies
``I = I0 a + b``; ``veil`` (scattered light of wet glass) then lowers the
contrast of the whole frame.

Mask convention: ``uint8`` ``(H, W)``, 255 inside the footprint of the
listed effects and 0 outside. The footprint comes from geometry, never from
pixel differences: the union of drop and blob outlines (where their coverage
is positive) grown by the defocus kernel's reach, the dust support, and the
whole frame when ``veil`` is listed (scattered light reaches every pixel).
Pixels outside the mask are copied from the input, so they are bit-identical
by construction; pixels inside may or may not change (decoding and encoding
an untouched pixel gives back its code exactly).

Instrumentation: ``hook(name)`` is called once per listed effect per
rendered frame, in ``EffectsSpec.listed`` order, as the effect is computed;
an unlisted effect's code is never reached (neither sampled nor applied).

Randomness: :func:`sample_glass` splits ``rng`` into one stream per effect,
so the same seed gives the same drops whether or not defocus, dust or dirt
are listed (:data:`~lenspair.simulate.effects.spec.SHARP_DROPS` and a defocused
variant show the same drops); :func:`apply_glass` draws nothing.
"""

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np

from lenspair.core.pixels import check_image, from_float, from_linear, to_linear
from lenspair.simulate.effects import brightness, defocus, dirt, dust, raindrops, veil
from lenspair.simulate.effects.layer import Placement, Sprites, composite_over, place, support_mask
from lenspair.simulate.effects.spec import EffectsSpec
from lenspair.simulate.errors import SimulateError

EffectHook = Callable[[str], None]
"""Called with an effect's name each time that effect is computed (instrumentation)."""

_STREAMS = ("raindrops", "brightness", "dirt", "defocus", "dust", "veil")


@dataclass(frozen=True, eq=False)
class GlassState:
    """Everything sampled about the glass for one frame size (drops, blobs, dust fields).

    Built by :func:`sample_glass`; fields of unlisted effects are ``None``.
    Everything here depends on the glass only, never on a frame, so a
    recording renders the same glass onto every frame at the per-frame cost
    of :func:`apply_glass` alone.

    Attributes:
        effects: the spec the state was sampled from.
        shape: image ``(H, W)``.
        drops: drop geometry.
        optics: per-pixel drop optics.
        gains: ``float32`` ``(N,)`` per-drop brightness gains.
        blobs: dirt blob geometry.
        dirt: dirt coverage.
        kernel: defocus correlation kernel.
        dust: dust fields.
        veiling: the veil of wet glass (strength and level).
        mask: ``uint8`` ``(H, W)`` footprint, 255 inside, 0 outside (read-only).
        indices: ``int64`` flat indices of the footprint pixels.
        margin: canvas margin of the glass layer, pixels.
        drop_placement: where drop pixels land on the glass canvas.
        dirt_placement: where dirt pixels land on the glass canvas.
        dust_at_mask: ``(a, b)`` at the footprint pixels, ``float32``.

    """

    effects: EffectsSpec
    shape: tuple[int, int]
    drops: raindrops.Drops | None
    optics: raindrops.DropOptics | None
    gains: np.ndarray | None
    blobs: dirt.Blobs | None
    dirt: Sprites | None
    kernel: np.ndarray | None
    dust: dust.DustField | None
    veiling: veil.Veil | None
    mask: np.ndarray
    indices: np.ndarray
    margin: int
    drop_placement: Placement | None
    dirt_placement: Placement | None
    dust_at_mask: tuple[np.ndarray, np.ndarray] | None


def _stream_seeds(rng: np.random.Generator) -> dict[str, int]:
    """One seed per effect, always all drawn: listing dust does not move the drops."""
    seeds = rng.integers(0, 2**63, size=len(_STREAMS))
    return {name: int(seed) for name, seed in zip(_STREAMS, seeds, strict=True)}


def sample_glass(
    effects: EffectsSpec, shape: tuple[int, int], rng: np.random.Generator
) -> GlassState:
    """Sample the glass state for images of ``shape`` = (H, W).

    Args:
        effects: what is on the glass; unlisted effects are not sampled.
        shape: image ``(H, W)``, both >= 1.
        rng: random generator; the same state and spec give the same glass.

    Returns:
        The glass state, with its footprint mask.

    Raises:
        SimulateError: ``shape`` is not two positive integers, or the drops or
            dirt would not fit in memory (:meth:`EffectsSpec.check_memory`).

    """
    if len(shape) != 2 or min(int(shape[0]), int(shape[1])) < 1:
        raise SimulateError(f"shape: expected (H, W) with H, W >= 1, got {tuple(shape)}")
    shape = (int(shape[0]), int(shape[1]))
    try:
        effects = effects.for_photograph()  # a scene's are set already (its camera's)
        effects.check_memory(shape)
    except ValueError as exc:
        raise SimulateError(str(exc)) from None
    seeds = _stream_seeds(rng)

    def stream(name: str) -> np.random.Generator:
        return np.random.default_rng(seeds[name])

    drops = gains = blobs = kernel = field = veiling = None
    if effects.raindrops is not None:
        drops = raindrops.sample_drops(effects.raindrops, shape, stream("raindrops"))
        if effects.brightness is not None:
            gains = brightness.sample_gains(effects.brightness, drops.count, stream("brightness"))
    if effects.dirt is not None:
        blobs = dirt.sample_blobs(effects.dirt, shape, stream("dirt"))
    if effects.defocus is not None:
        shifts = defocus.sample_shifts(effects.defocus, stream("defocus"))
        kernel = defocus.blur_kernel(shifts, effects.defocus.disk_px)
    if effects.dust is not None:
        field = dust.sample_dust(effects.dust, shape, stream("dust"))
    if effects.veil is not None:
        veiling = veil.sample_veil(effects.veil, stream("veil"))
    return _assemble(effects, shape, drops, gains, blobs, kernel, field, veiling)


def advance_glass(glass: GlassState, rng: np.random.Generator) -> GlassState:
    """The glass one frame later: each drop stays with probability ``persistence``.

    Replaced drops (and their brightness gains) are drawn afresh; blobs, dust
    and defocus stay. With ``persistence == 1`` (the default) the same state
    is returned.

    Args:
        glass: the current state.
        rng: random generator.

    Returns:
        The next state.

    """
    spec = glass.effects.raindrops
    if spec is None or glass.drops is None or spec.persistence >= 1.0:
        return glass
    keep = rng.random(glass.drops.count) < spec.persistence
    drops = glass.drops.select(keep, raindrops.sample_drops(spec, glass.shape, rng))
    # the gains' own stream, always drawn: listing brightness does not move later drops
    gain_rng = np.random.default_rng(int(rng.integers(0, 2**63)))
    gains = glass.gains
    if gains is not None and glass.effects.brightness is not None:
        fresh = brightness.sample_gains(glass.effects.brightness, drops.count, gain_rng)
        gains = np.where(keep, gains, fresh).astype(np.float32)
    return _assemble(
        glass.effects,
        glass.shape,
        drops,
        gains,
        glass.blobs,
        glass.kernel,
        glass.dust,
        glass.veiling,
    )


def without_effect(glass: GlassState, name: str) -> GlassState:
    """``glass`` as if ``name`` (``raindrops``, ``dirt``, ``dust`` or ``veil``) were not listed.

    Everything else sampled stays as drawn; the drops go with their
    brightness gains. What a frame through it lacks is what ``name`` did
    (:mod:`lenspair.simulate.labels`).

    Raises:
        ValueError: ``name`` is not one of the four.
    """
    effects, drops, gains = glass.effects, glass.drops, glass.gains
    blobs, field, veiling = glass.blobs, glass.dust, glass.veiling
    if name == "raindrops":
        effects, drops, gains = replace(effects, raindrops=None, brightness=None), None, None
    elif name == "dirt":
        effects, blobs = replace(effects, dirt=None), None
    elif name == "dust":
        effects, field = replace(effects, dust=None), None
    elif name == "veil":
        effects, veiling = replace(effects, veil=None), None
    else:
        raise ValueError(f"not an effect that can be left out: {name!r}")
    return _assemble(effects, glass.shape, drops, gains, blobs, glass.kernel, field, veiling)


def _assemble(
    effects: EffectsSpec,
    shape: tuple[int, int],
    drops: raindrops.Drops | None,
    gains: np.ndarray | None,
    blobs: dirt.Blobs | None,
    kernel: np.ndarray | None,
    field: dust.DustField | None,
    veiling: veil.Veil | None = None,
) -> GlassState:
    """Rasterise the sampled geometry and compute the footprint."""
    half = 0 if kernel is None else kernel.shape[0] // 2
    margin = 2 * half  # sprites reach `half` beyond the image, the blur reads `half` more
    canvas_shape = (shape[0] + 2 * margin, shape[1] + 2 * margin)
    optics = blob_sprites = drop_placement = dirt_placement = None
    footprint: np.ndarray = np.zeros(canvas_shape, np.uint8)
    if drops is not None and effects.raindrops is not None:
        optics = raindrops.rasterize(drops, effects.raindrops, shape, half)
        drop_placement = place(optics.sprites, shape, margin)
        footprint |= support_mask(drop_placement, canvas_shape)
    if blobs is not None:
        blob_sprites = dirt.rasterize(blobs, shape, half)
        dirt_placement = place(blob_sprites, shape, margin)
        footprint |= support_mask(dirt_placement, canvas_shape)
    if kernel is not None and footprint.any():
        element = defocus.grow_element(defocus.kernel_reach(kernel))
        footprint = cv2.dilate(footprint, element, borderType=cv2.BORDER_CONSTANT, borderValue=0)
    mask = np.ascontiguousarray(footprint[margin : margin + shape[0], margin : margin + shape[1]])
    if field is not None:
        mask[field.support] = 255
    if veiling is not None and veiling.strength > 0:
        mask[:] = 255  # scattered light reaches every pixel
    indices = np.flatnonzero(mask)
    dust_at_mask = None
    if field is not None:
        dust_at_mask = (
            np.take(field.transmission.reshape(-1), indices),
            np.take(field.veil.reshape(-1), indices),
        )
    for array in (mask, gains, kernel, indices):
        if array is not None:
            array.setflags(write=False)
    return GlassState(
        effects=effects,
        shape=shape,
        drops=drops,
        optics=optics,
        gains=gains,
        blobs=blobs,
        dirt=blob_sprites,
        kernel=kernel,
        dust=field,
        veiling=veiling,
        mask=mask,
        indices=indices,
        margin=margin,
        drop_placement=drop_placement,
        dirt_placement=dirt_placement,
        dust_at_mask=dust_at_mask,
    )


def _linearize(image: np.ndarray) -> np.ndarray:
    """Integer sRGB image to ``float32`` ``(H, W, C)`` linear light, by table lookup."""
    lut = _decode_table(image.dtype)
    # cv2.LUT is ~4x faster than fancy indexing but only takes 8-bit input.
    linear = cv2.LUT(image, lut) if image.dtype == np.uint8 else np.take(lut, image)
    return np.asarray(linear, np.float32).reshape(image.shape[0], image.shape[1], -1)


_TABLES: dict[str, np.ndarray] = {}


def _decode_table(dtype: np.dtype) -> np.ndarray:
    """Linear value of every code of an integer dtype (256 or 65536 entries)."""
    key = np.dtype(dtype).str
    if key not in _TABLES:
        top = np.iinfo(dtype).max
        codes = np.arange(top + 1, dtype=np.float32) / np.float32(top)
        table = to_linear(codes)
        table.setflags(write=False)
        _TABLES[key] = table
    return _TABLES[key]


def _encode(values: np.ndarray, dtype: np.dtype | type) -> np.ndarray:
    """Linear float32 values to integer codes: the single clip of the pipeline."""
    return from_float(from_linear(values), dtype)


def apply_glass(
    image: np.ndarray, glass: GlassState, hook: EffectHook | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Render ``glass`` over a clean image.

    Args:
        image: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)``, sRGB-encoded,
            with ``(H, W) == glass.shape``.
        glass: from :func:`sample_glass`.
        hook: called with each listed effect's name as it is computed.

    Returns:
        ``(obstructed, mask)``: the image with the effects, same dtype and
        shape as ``image`` and bit-identical outside the mask; the ``uint8``
        ``(H, W)`` footprint mask (255 inside, 0 outside).

    Raises:
        SimulateError: wrong dtype or shape.

    """
    try:
        check_image(image)
    except ValueError as exc:
        raise SimulateError(str(exc)) from None
    _check_shape(image, glass)
    out = np.array(image, copy=True, order="C")
    if _covers_nothing(glass, hook):  # nothing to decode, change or encode
        return out, glass.mask.copy()
    values = _through_glass(_linearize(image), glass, hook)
    out.reshape(-1, values.shape[1])[glass.indices] = _encode(values, image.dtype)
    return out, glass.mask.copy()


def apply_glass_linear(
    light: np.ndarray, glass: GlassState, hook: EffectHook | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`apply_glass` on linear light before the camera clips it.

    For a simulated camera (:func:`~lenspair.simulate.sensor.expose_through_glass`):
    light over full scale (a lamp, a sunlit sky) stays over it while drops
    refract and the defocus blurs it, so a drop over it blooms to saturation
    as on a real lens, and the camera clips and quantises once, after the
    glass.

    Args:
        light: ``float32`` ``(H, W)`` or ``(H, W, C)`` linear light, ``>= 0``,
            any level (unclipped), with ``(H, W) == glass.shape``.
        glass: from :func:`sample_glass`.
        hook: as :func:`apply_glass`.

    Returns:
        ``(light through the glass, mask)``: ``float32``, the input's shape,
        bit-identical outside the mask; the mask as :func:`apply_glass`.

    Raises:
        SimulateError: wrong shape.

    """
    if light.ndim not in (2, 3):
        raise SimulateError(f"light: expected (H, W) or (H, W, C), got shape {light.shape}")
    _check_shape(light, glass)
    out = np.array(light, dtype=np.float32, copy=True, order="C")
    if _covers_nothing(glass, hook):
        return out, glass.mask.copy()
    values = _through_glass(out.reshape(out.shape[0], out.shape[1], -1), glass, hook)
    out.reshape(-1, values.shape[1])[glass.indices] = values
    return out, glass.mask.copy()


def _check_shape(image: np.ndarray, glass: GlassState) -> None:
    if image.shape[:2] != glass.shape:
        raise SimulateError(f"image: expected (H, W) = {glass.shape}, got {image.shape[:2]}")


def _covers_nothing(glass: GlassState, hook: EffectHook | None) -> bool:
    """Whether nothing is listed or nothing on the glass covers a pixel (each listed one said)."""
    if glass.indices.size:
        return False
    for name in glass.effects.listed:
        (hook or _ignore)(name)
    return True


def _through_glass(linear: np.ndarray, glass: GlassState, hook: EffectHook | None) -> np.ndarray:
    """Linear light at the footprint pixels after the glass, ``(M, C)``.

    ``linear`` is the whole frame, ``float32`` ``(H, W, C)``; the footprint is
    not empty (:func:`_covers_nothing`).
    """
    effects = glass.effects
    notify = hook if hook is not None else _ignore
    channels = linear.shape[2]
    values = np.take(linear.reshape(-1, channels), glass.indices, axis=0)
    light = None
    if effects.veil is not None and glass.veiling is not None:
        light = veil.veil_light(values, glass.veiling)  # the footprint is the whole frame
    if glass.optics is not None or glass.dirt is not None:
        layer = _glass_layer(linear, glass, notify)
        values = layer[:, :channels] + (1.0 - layer[:, channels:]) * values
    else:
        for name in ("brightness", "defocus"):
            if getattr(effects, name) is not None:
                notify(name)  # listed, but there is nothing on the glass to act on
    if effects.dust is not None and glass.dust_at_mask is not None:
        notify("dust")
        values = dust.apply_dust(values, *glass.dust_at_mask)
    if light is not None and glass.veiling is not None:
        notify("veil")
        values = veil.apply_veil(values, light, glass.veiling.strength)
    return np.asarray(values, np.float32)


def _glass_layer(linear: np.ndarray, glass: GlassState, notify: EffectHook) -> np.ndarray:
    """Premultiplied glass layer (drops, brightness, dirt, defocus) at the footprint pixels.

    ``linear`` is the whole frame's light, ``float32`` ``(H, W, C)``.

    Returns:
        ``float32`` ``(len(glass.indices), C + 1)``: colour then coverage.

    """
    effects = glass.effects
    channels = linear.shape[2]
    height, width = glass.shape
    margin = glass.margin
    canvas = np.zeros((height + 2 * margin, width + 2 * margin, channels + 1), np.float32)
    boxes = []
    if effects.raindrops is not None and glass.optics is not None:
        notify("raindrops")
        colour = raindrops.shade(linear, glass.optics, effects.raindrops.rim_brightness)
        if effects.brightness is not None and glass.gains is not None:
            notify("brightness")
            colour = brightness.brighten(colour, glass.optics.sprites.owner, glass.gains)
        alpha = glass.optics.sprites.alpha
        assert glass.drop_placement is not None
        composite_over(canvas, glass.drop_placement, colour * alpha[:, None], alpha, empty=True)
        boxes.append(glass.optics.sprites.boxes)
    elif effects.brightness is not None:
        notify("brightness")  # no drops to brighten
    if effects.dirt is not None and glass.dirt is not None:
        notify("dirt")
        colour = dirt.premultiplied(glass.dirt, effects.dirt.color, channels)
        assert glass.dirt_placement is not None
        composite_over(canvas, glass.dirt_placement, colour, glass.dirt.alpha)
        boxes.append(glass.dirt.boxes)
    if effects.defocus is not None and glass.kernel is not None:
        notify("defocus")
        canvas = defocus.blur_layer(canvas, margin, np.concatenate(boxes), glass.kernel)
    flat: np.ndarray = np.take(canvas.reshape(-1, channels + 1), glass.indices, axis=0)
    return flat


def _ignore(name: str) -> None:
    """Default hook: do nothing."""


def render_effects(
    image: np.ndarray,
    effects: EffectsSpec,
    rng: np.random.Generator,
    hook: EffectHook | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Render ``effects`` over a clean image (sample + apply in one call).

    Args:
        image: ``uint8``/``uint16`` ``(H, W)`` or ``(H, W, 3)``, sRGB-encoded.
        effects: what is on the glass.
        rng: random generator.
        hook: called with each listed effect's name as it is computed.

    Returns:
        ``(obstructed, mask)`` as :func:`apply_glass`.

    """
    return apply_glass(image, sample_glass(effects, image.shape[:2], rng), hook)
