"""What a scene declares about the glass in front of the obstructed camera.

An effect is enabled by listing its key under ``effects:`` in a scene spec
(``effects: {raindrops: {count: 50}, defocus: {}}``); a key that is absent is
``None`` here and its effect is never computed. Ranges are ``(min, max)``
pairs sampled uniformly per drop/blob with the caller's generator. Every
intensity (gains, veils, colours) is in *linear* light, ``[0, 1]`` = black to
the brightest code value.
"""

import dataclasses
from dataclasses import dataclass
from typing import Literal

PHOTO_FOCAL_PX = 350.0
"""The drops' focal length over a photograph, pixels: the sample camchain's ``fx``."""

PHOTO_PIXEL_PITCH_UM = 6.9
"""The defocus's pixel pitch over a photograph: the Sony IMX287 (see :class:`DefocusSpec`)."""

MAX_COUNT = 100_000
"""Most drops or blobs on one glass: far beyond a real pane."""

MAX_SPRITE_PIXELS = 20_000_000
"""Most pixels the boxes of one glass's drops (or blobs) may hold in a frame.

The renderer keeps about 130 bytes for each (coordinates, refraction,
coverage): 2.6 GB at this bound, which a spec like ``count: 250,
radius_px: [3, 60]`` (the ``ours`` preset) stays 5x below at its largest.
"""


def _check_range(name: str, value: tuple[float, float], low: float, high: float) -> None:
    lo, hi = value
    if not (low <= lo <= hi <= high):
        raise ValueError(f"{name}: expected {low} <= min <= max <= {high}, got {value}")


def _check_value(name: str, value: float, low: float, high: float) -> None:
    if not low <= value <= high:
        raise ValueError(f"{name}: expected {low}..{high}, got {value}")


MIN_POWER_LAW_RADIUS_PX = 0.5
"""Smallest ``radius_px`` lower bound of ``power-law`` drops: below it (0 included, where
``r^-k`` has no finite mass) nearly every drop is sub-pixel and the declared rain leaves
no trace while the recording is labelled rain."""

MIN_SHIFTS = 4
"""Fewest random shifts that blur the glass layer: one translates it, two or three
double or triple it."""


@dataclass(frozen=True)
class RaindropsSpec:
    """Drops on the glass, rendered as small spherical-cap lenses.

    Attributes:
        count: number of drops on the glass.
        radius_px: semi-major axis range of a drop's footprint, pixels.
        aspect: ratio of minor to major axis (1 = round), range.
        contact_angle_deg: angle between glass and drop surface at the rim,
            range, degrees; larger angles give stronger lenses, and above the
            critical angle ``asin(1/n)`` (48.8° for water) a dark rim of
            totally internally reflected rays appears.
        refractive_index: of water, 1.33; 1.0 makes the drops invisible.
        persistence: probability that a drop stays put when a recording
            advances the glass state (:func:`lenspair.simulate.render.advance_glass`);
            the others are replaced by fresh drops. 1 = drops never move.
        focal_px: focal length of the camera, pixels; converts the angle by
            which a drop bends a viewing ray into an image offset. ``None``:
            the obstructed camera's ``fx`` in a recording scene, and
            :data:`PHOTO_FOCAL_PX` over a photograph (no camera given).
        rim_brightness: linear-light brightness of light reflected inside a
            drop (the totally internally reflected rim), as a fraction of the
            mean colour the drop transmits.
        size_distribution: how ``radius_px`` is sampled: ``uniform`` (Porav
            et al.'s synthetic drops), or ``power-law``: density
            ``~ r^-size_exponent`` over ``radius_px``, so many small drops
            and a few large merged ones, as on real wet glass.
        size_exponent: exponent of the power law (> 1 favours small drops).

    """

    count: int = 50
    radius_px: tuple[float, float] = (5.0, 25.0)
    aspect: tuple[float, float] = (0.7, 1.0)
    contact_angle_deg: tuple[float, float] = (30.0, 80.0)
    refractive_index: float = 1.33
    persistence: float = 1.0
    focal_px: float | None = None
    rim_brightness: float = 0.1
    size_distribution: Literal["uniform", "power-law"] = "uniform"
    size_exponent: float = 2.0

    def __post_init__(self) -> None:
        if not 0 <= self.count <= MAX_COUNT:
            raise ValueError(f"count: expected 0..{MAX_COUNT}, got {self.count}")
        _check_range("radius_px", self.radius_px, 0.0, 1e3)
        _check_range("aspect", self.aspect, 0.05, 1.0)
        _check_range("contact_angle_deg", self.contact_angle_deg, 0.0, 90.0)
        _check_value("refractive_index", self.refractive_index, 1.0, 3.0)
        _check_value("persistence", self.persistence, 0.0, 1.0)
        if self.focal_px is not None:
            _check_value("focal_px", self.focal_px, 1.0, 1e5)
        _check_value("rim_brightness", self.rim_brightness, 0.0, 1.0)
        if self.size_distribution not in ("uniform", "power-law"):
            raise ValueError(
                f"size_distribution: expected uniform or power-law, got {self.size_distribution!r}"
            )
        _check_value("size_exponent", self.size_exponent, 0.0, 10.0)
        if self.size_distribution == "power-law" and self.radius_px[0] < MIN_POWER_LAW_RADIUS_PX:
            raise ValueError(
                f"radius_px: power-law sizes need a smallest radius of at least "
                f"{MIN_POWER_LAW_RADIUS_PX} px, got {self.radius_px[0]:g}: the law piles most "
                "drops at the smallest radius, and drops under a pixel draw nothing"
            )

    @property
    def optics_focal_px(self) -> float:
        """The focal length the drop optics use, pixels (``focal_px``, else the photo default)."""
        return PHOTO_FOCAL_PX if self.focal_px is None else self.focal_px


@dataclass(frozen=True)
class DefocusSpec:
    """The glass is out of focus: blur the glass layer (drops and dirt).

    A camera focused far away sees a point on glass at distance ``d`` as a
    disk of diameter ``f_px * A / d`` pixels (thin lens), with the aperture
    diameter ``A = focal_length / f_number`` and ``f_px = focal_length /
    pixel_pitch``. The defaults are an Alphasense Core-like robot camera
    behind a glass panel 3 cm away: 2.4 mm lens at f/2.0 on a 6.9 um pixel
    (Sony IMX287 global shutter, 720x540), so ``f_px = 348`` (the sample
    camchain's ``fx`` is 350) and the blur disk is 13.9 px across. (The focal
    length and pitch follow from the sample camchain and the sensor's data
    sheet; the f-number is typical of such wide-angle M12 lenses, not a
    published Alphasense figure.)

    The blur's *shape* is the paper's: the layer averaged over ``shifts``
    random shifts drawn uniformly in a disk of the blur radius (its
    ``shift_px``). ``kernel: disk`` uses the thin-lens disk itself instead,
    and ``shift_px`` / ``disk_radius_px`` set pixel sizes by hand (they
    override the optics).

    Attributes:
        shifts: number of random shifts averaged (the paper's method).
        shift_px: largest shift, pixels; ``None``: the blur radius from
            the optics (with ``kernel: shifts``), else 0.
        disk_radius_px: thin-lens disk blur radius, pixels; ``None``: the
            blur radius from the optics (with ``kernel: disk``), else 0.
        kernel: ``shifts`` (the paper's averaged shifts) or ``disk``.
        glass_distance_m: distance from the lens to the glass, metres.
        focal_length_mm: lens focal length, millimetres.
        f_number: the lens's f-number (aperture diameter = focal / f_number).
        pixel_pitch_um: sensor pixel pitch, micrometres. ``None``: the
            focal length over the obstructed camera's ``fx`` in a recording
            scene (so the blur follows that camera), and
            :data:`PHOTO_PIXEL_PITCH_UM` over a photograph.

    """

    shifts: int = 16
    shift_px: float | None = None
    disk_radius_px: float | None = None
    kernel: Literal["shifts", "disk"] = "shifts"
    glass_distance_m: float = 0.03
    focal_length_mm: float = 2.4
    f_number: float = 2.0
    pixel_pitch_um: float | None = None

    def __post_init__(self) -> None:
        if not 1 <= self.shifts <= 256:
            raise ValueError(f"shifts: expected 1..256, got {self.shifts}")
        shifted = (self.shift_px is None and self.kernel == "shifts") or bool(self.shift_px)
        if shifted and self.shifts < MIN_SHIFTS:
            raise ValueError(
                f"shifts: expected at least {MIN_SHIFTS} where the layer is shifted (fewer move "
                f"or double the drops instead of blurring them), got {self.shifts}"
            )
        if self.shift_px is not None:
            _check_value("shift_px", self.shift_px, 0.0, 64.0)
        if self.disk_radius_px is not None:
            _check_value("disk_radius_px", self.disk_radius_px, 0.0, 64.0)
        if self.kernel not in ("shifts", "disk"):
            raise ValueError(f"kernel: expected shifts or disk, got {self.kernel!r}")
        _check_value("glass_distance_m", self.glass_distance_m, 1e-3, 10.0)
        _check_value("focal_length_mm", self.focal_length_mm, 0.1, 1e3)
        _check_value("f_number", self.f_number, 0.5, 64.0)
        if self.pixel_pitch_um is not None:  # else the camera decides (for_camera, for_photograph)
            _check_value("pixel_pitch_um", self.pixel_pitch_um, 0.1, 100.0)
            self.check_blur()

    def check_blur(self) -> None:
        """Refuse a blur disk over 128 px where the optics, not a pixel size, set it.

        Raises:
            ValueError: naming ``glass_distance_m``.
        """
        if self.blur_diameter_px / 2 > 64.0 and self.sized_by_optics:
            raise ValueError(
                f"glass_distance_m: blur disk of {self.blur_diameter_px:.0f} px (f_px * A / d, "
                "set by it with focal_length_mm, f_number and the pixel size) is over 128 px; "
                "move the glass away, give a shorter focal_length_mm, a larger f_number or "
                "larger pixels, or set shift_px/disk_radius_px"
            )

    @property
    def sized_by_optics(self) -> bool:
        """Whether the optics size the kernel (``shift_px``/``disk_radius_px`` unset)."""
        return self.shift_px is None if self.kernel == "shifts" else self.disk_radius_px is None

    @property
    def focal_px(self) -> float:
        """Focal length in pixels, ``focal_length / pixel_pitch``."""
        pitch = PHOTO_PIXEL_PITCH_UM if self.pixel_pitch_um is None else self.pixel_pitch_um
        return self.focal_length_mm * 1e3 / pitch

    @property
    def blur_diameter_px(self) -> float:
        """Thin-lens blur disk diameter of the glass, ``f_px * A / d``, pixels."""
        aperture_mm = self.focal_length_mm / self.f_number
        return self.focal_px * aperture_mm / (self.glass_distance_m * 1e3)

    @property
    def shift_radius_px(self) -> float:
        """Largest shift actually used, pixels."""
        if self.shift_px is not None:
            return self.shift_px
        return self.blur_diameter_px / 2 if self.kernel == "shifts" else 0.0

    @property
    def disk_px(self) -> float:
        """Disk blur radius actually used, pixels."""
        if self.disk_radius_px is not None:
            return self.disk_radius_px
        return self.blur_diameter_px / 2 if self.kernel == "disk" else 0.0


@dataclass(frozen=True)
class VeilSpec:
    """Wet glass scatters light over the whole frame: a veil that lowers contrast.

    ``I = (1 - s) * I0 + s * level * mean(I0)`` in linear light, per
    channel: a share ``s`` of the light reaching each pixel is replaced by
    light scattered from the whole scene (its mean), brightened by
    ``level`` (drops and the water film catch light from bright parts of
    the scene, e.g. the sky). Contrast (the standard deviation in linear
    light) drops by exactly ``1 - s`` everywhere, not only inside drops.
    ``s`` and ``level`` are drawn once per glass state.

    Attributes:
        strength: range of the scattered share ``s`` (0 = clear glass).
        level: range of the veil's brightness relative to the scene mean.

    """

    strength: tuple[float, float] = (0.1, 0.2)
    level: tuple[float, float] = (1.0, 1.5)

    def __post_init__(self) -> None:
        _check_range("strength", self.strength, 0.0, 1.0)
        _check_range("level", self.level, 0.0, 10.0)


@dataclass(frozen=True)
class BrightnessSpec:
    """Brighten a random subset of drops, as seen on real rigs.

    Attributes:
        fraction: probability that a drop is brightened.
        gain: multiplicative gain range in linear light, 0..100. Gains below 1
            darken the chosen drops instead (0: black), for glass that shades
            rather than glows.

    """

    fraction: float = 0.3
    gain: tuple[float, float] = (1.1, 1.5)

    def __post_init__(self) -> None:
        _check_value("fraction", self.fraction, 0.0, 1.0)
        _check_range("gain", self.gain, 0.0, 100.0)


@dataclass(frozen=True)
class DustSpec:
    """Low-frequency attenuation and scattering: ``I = I0 * a + b``.

    ``a = exp(-tau)`` where the optical depth ``tau`` is a sum of smooth
    compactly supported bumps, and ``b = scatter * (1 - a)``: outside the
    bumps ``a = 1`` and ``b = 0`` exactly.

    Attributes:
        attenuation: range of the transmission ``a`` at the centre of one
            dust patch (1 = clear); overlapping patches multiply.
        scatter: veil added per unit of blocked light, linear light.
        scale_px: radius of the largest dust patch, pixels (patches are
            ``scale_px * U(0.5, 1)``).
        coverage: expected fraction of the image under dust (the union of
            the patches); 0 = no patch.

    """

    attenuation: tuple[float, float] = (0.6, 0.9)
    scatter: float = 0.08
    scale_px: float = 80.0
    coverage: float = 0.5

    def __post_init__(self) -> None:
        _check_range("attenuation", self.attenuation, 0.0, 1.0)
        _check_value("scatter", self.scatter, 0.0, 1.0)
        _check_value("scale_px", self.scale_px, 4.0, 1e4)
        _check_value("coverage", self.coverage, 0.0, 1.0)


@dataclass(frozen=True)
class DirtSpec:
    """Opaque and semi-transparent blobs of dirt on the glass.

    Attributes:
        count: number of blobs.
        radius_px: blob radius range, pixels.
        opacity: opacity range (1 = opaque).
        color: linear-light grey level of the dirt.
        irregularity: amplitude of the outline's wiggles relative to the
            radius (0 = round discs).

    """

    count: int = 6
    radius_px: tuple[float, float] = (8.0, 40.0)
    opacity: tuple[float, float] = (0.5, 1.0)
    color: float = 0.05
    irregularity: float = 0.3

    def __post_init__(self) -> None:
        if not 0 <= self.count <= MAX_COUNT:
            raise ValueError(f"count: expected 0..{MAX_COUNT}, got {self.count}")
        _check_range("radius_px", self.radius_px, 0.0, 1e3)
        _check_range("opacity", self.opacity, 0.0, 1.0)
        _check_value("color", self.color, 0.0, 1.0)
        _check_value("irregularity", self.irregularity, 0.0, 0.6)


@dataclass(frozen=True)
class EffectsSpec:
    """The effects on one camera's glass; ``None`` means not listed, never computed."""

    raindrops: RaindropsSpec | None = None
    defocus: DefocusSpec | None = None
    brightness: BrightnessSpec | None = None
    dust: DustSpec | None = None
    dirt: DirtSpec | None = None
    veil: VeilSpec | None = None

    def check_memory(self, shape: tuple[int, int]) -> None:
        """Refuse drops or dirt whose pixels would not fit in memory on an ``(H, W)`` frame.

        The bound is on the worst case (every drop or blob at the largest
        radius), so a spec that passes renders on every frame of a recording.

        Raises:
            ValueError: naming the effect, its worst case and the bound.
        """
        height, width = shape
        reaches = []  # (key, noun, count, largest radius, largest reach from the centre)
        if self.raindrops is not None:
            radius = self.raindrops.radius_px[1]
            reaches.append(("raindrops", "drops", self.raindrops.count, radius, radius + 1.0))
        if self.dirt is not None:
            radius = self.dirt.radius_px[1]
            wiggle = radius * (1.0 + self.dirt.irregularity) + 1.0
            reaches.append(("dirt", "blobs", self.dirt.count, radius, wiggle))
        for name, things, count, radius, reach in reaches:
            side = 2.0 * reach + 3.0  # a box, rounded out
            pixels = count * min(side, height) * min(side, width)
            if pixels > MAX_SPRITE_PIXELS:
                raise ValueError(
                    f"{name}: {count} {things} of radius up to {radius:g} px cover up to "
                    f"{pixels:.3g} pixels of a {width}x{height} frame, more than the renderer's "
                    f"{MAX_SPRITE_PIXELS:.0e} (about 2.6 GB); use fewer or smaller {things}"
                )

    def for_camera(self, fx: float) -> "EffectsSpec":
        """These effects in front of a camera of focal length ``fx`` pixels.

        Optics left unset take the camera's: the drops' ``focal_px`` and
        the defocus's pixel pitch (``focal_length_mm / fx``, so its blur
        disk is ``fx * A / d``). Set values stay.

        Raises:
            ValueError: the camera makes the defocus impossible (a blur disk
                over 128 px, a pitch out of range where the optics size the
                blur), named by its key.
        """
        pitch = None
        if self.defocus is not None and self.defocus.pixel_pitch_um is None:
            pitch = self.defocus.focal_length_mm * 1e3 / fx
            if not 0.1 <= pitch <= 100.0:
                if self.defocus.sized_by_optics:
                    raise ValueError(
                        f"defocus.pixel_pitch_um: focal_length_mm "
                        f"{self.defocus.focal_length_mm:g} over the camera's fx {fx:g} px is a "
                        f"{pitch:.3g} um pixel, outside 0.1..100; set focal_length_mm or "
                        "pixel_pitch_um"
                    )
                pitch = None  # a blur sized by hand: the camera's pixel is not used
        try:
            return self._with_optics(min(max(fx, 1.0), 1e5), pitch)
        except ValueError as exc:
            raise ValueError(f"defocus.{exc} (with the camera's fx {fx:g} px)") from None

    def for_photograph(self) -> "EffectsSpec":
        """These effects over a photograph (no camera): unset optics take the photo defaults.

        Raises:
            ValueError: the defocus's blur disk would be over 128 px.
        """
        return self._with_optics(PHOTO_FOCAL_PX, PHOTO_PIXEL_PITCH_UM)

    def _with_optics(self, focal_px: float, pitch_um: float | None) -> "EffectsSpec":
        """The drops' ``focal_px`` and the defocus's pixel pitch where unset (checked)."""
        drops, defocus = self.raindrops, self.defocus
        if drops is not None and drops.focal_px is None:
            drops = dataclasses.replace(drops, focal_px=focal_px)
        if defocus is not None and defocus.pixel_pitch_um is None:
            defocus = dataclasses.replace(defocus, pixel_pitch_um=pitch_um)
        return dataclasses.replace(self, raindrops=drops, defocus=defocus)

    @property
    def listed(self) -> tuple[str, ...]:
        """Names of the listed effects, in rendering order."""
        order = ("raindrops", "brightness", "dirt", "defocus", "dust", "veil")
        return tuple(name for name in order if getattr(self, name) is not None)

    @property
    def anomaly_kinds(self) -> tuple[str, ...]:
        """Anomaly labels for ``rig.yaml``: ``rain``, ``dust``, ``dirt``.

        A veil is glass scattering light. Alone it is wet glass, ``rain`` (a
        frame it changes everywhere is not clean, and a detector must not learn
        it is); beside dust or dirt it is that dirty glass's haze and adds no
        label, as the detector's ``veiled_dust`` hard case is labelled ``dust``.
        An effect that changes no pixel gives no label: no drops, drops of
        radius 0 or of refractive index 1 (optically absent: the renderer
        gives them no footprint, so brightening has nothing to act on), no
        dust coverage or dust that attenuates nothing, no blobs or blobs of
        radius or opacity 0, a veil of strength 0. Such a camera's frames
        are clean, and a dataset or detector trained on them must say so. A
        recording also leaves out an effect its sampled glass holds nothing of
        (no dust patch drawn), then applies these rules to what is left.
        """
        kinds = []
        drops = self.raindrops
        seen = (
            drops is not None
            and drops.count > 0
            and drops.radius_px[1] > 0
            and drops.refractive_index != 1.0
        )
        dust, dirt = self.dust, self.dirt
        dusty = dust is not None and dust.coverage > 0 and dust.attenuation[0] < 1.0
        dirty = (
            dirt is not None and dirt.count > 0 and dirt.radius_px[1] > 0 and dirt.opacity[1] > 0
        )
        veiled = self.veil is not None and self.veil.strength[1] > 0
        if seen or (veiled and not (dusty or dirty)):
            kinds.append("rain")
        if dusty:
            kinds.append("dust")
        if dirty:
            kinds.append("dirt")
        return tuple(kinds)


SHARP_DROPS = EffectsSpec(raindrops=RaindropsSpec())
"""Porav et al.'s in-focus synthetic drops: raindrops without defocus and brightness."""
