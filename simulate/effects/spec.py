"""What a scene declares about the glass in front of the obstructed camera.

An effect is enabled by listing its key under ``effects:`` in a scene spec
(``effects: {raindrops: {count: 50}, defocus: {}}``); a key that is absent is
``None`` here and its effect is never computed. Ranges are ``(min, max)``
pairs sampled uniformly per drop/blob with the caller's generator. Every
intensity (gains, veils, colours) is in *linear* light, ``[0, 1]`` = black to
the brightest code value.
"""

from dataclasses import dataclass


def _check_range(name: str, value: tuple[float, float], low: float, high: float) -> None:
    lo, hi = value
    if not (low <= lo <= hi <= high):
        raise ValueError(f"{name}: expected {low} <= min <= max <= {high}, got {value}")


def _check_value(name: str, value: float, low: float, high: float) -> None:
    if not low <= value <= high:
        raise ValueError(f"{name}: expected {low}..{high}, got {value}")


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
            which a drop bends a viewing ray into an image offset.
        rim_brightness: linear-light brightness of light reflected inside a
            drop (the totally internally reflected rim), as a fraction of the
            mean colour the drop transmits.

    """

    count: int = 50
    radius_px: tuple[float, float] = (5.0, 25.0)
    aspect: tuple[float, float] = (0.7, 1.0)
    contact_angle_deg: tuple[float, float] = (30.0, 80.0)
    refractive_index: float = 1.33
    persistence: float = 1.0
    focal_px: float = 350.0
    rim_brightness: float = 0.1

    def __post_init__(self) -> None:
        if self.count < 0:
            raise ValueError(f"count: expected >= 0, got {self.count}")
        _check_range("radius_px", self.radius_px, 0.0, 1e3)
        _check_range("aspect", self.aspect, 0.05, 1.0)
        _check_range("contact_angle_deg", self.contact_angle_deg, 0.0, 90.0)
        _check_value("refractive_index", self.refractive_index, 1.0, 3.0)
        _check_value("persistence", self.persistence, 0.0, 1.0)
        _check_value("focal_px", self.focal_px, 1.0, 1e5)
        _check_value("rim_brightness", self.rim_brightness, 0.0, 1.0)


@dataclass(frozen=True)
class DefocusSpec:
    """The glass is out of focus: blur the glass layer (drops and dirt).

    Attributes:
        shifts: number of random shifts averaged (the paper's method).
        shift_px: largest shift, pixels; shifts are uniform in a disk.
        disk_radius_px: optional thin-lens disk blur radius (0 = off).

    """

    shifts: int = 8
    shift_px: float = 3.0
    disk_radius_px: float = 0.0

    def __post_init__(self) -> None:
        if not 1 <= self.shifts <= 256:
            raise ValueError(f"shifts: expected 1..256, got {self.shifts}")
        _check_value("shift_px", self.shift_px, 0.0, 64.0)
        _check_value("disk_radius_px", self.disk_radius_px, 0.0, 64.0)


@dataclass(frozen=True)
class BrightnessSpec:
    """Brighten a random subset of drops, as seen on real rigs.

    Attributes:
        fraction: probability that a drop is brightened.
        gain: multiplicative gain range in linear light.

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
        if self.count < 0:
            raise ValueError(f"count: expected >= 0, got {self.count}")
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

    @property
    def listed(self) -> tuple[str, ...]:
        """Names of the listed effects, in rendering order."""
        order = ("raindrops", "brightness", "dirt", "defocus", "dust")
        return tuple(name for name in order if getattr(self, name) is not None)

    @property
    def anomaly_kinds(self) -> tuple[str, ...]:
        """Anomaly labels for ``rig.yaml``: ``rain``, ``dust``, ``dirt``."""
        kinds = []
        if self.raindrops is not None:
            kinds.append("rain")
        if self.dust is not None:
            kinds.append("dust")
        if self.dirt is not None:
            kinds.append("dirt")
        return tuple(kinds)


SHARP_DROPS = EffectsSpec(raindrops=RaindropsSpec())
"""Porav et al.'s in-focus synthetic drops: raindrops without defocus and brightness."""
