"""What a scene declares about the glass in front of the obstructed camera.

An effect is enabled by listing its key under ``effects:`` in a scene spec
(``effects: {raindrops: {count: 50}, defocus: {}}``); a key that is absent is
``None`` here and its effect is never computed. Ranges are ``(min, max)``
pairs sampled uniformly per drop/blob with the caller's generator.
"""

from dataclasses import dataclass


def _check_range(name: str, value: tuple[float, float], low: float, high: float) -> None:
    lo, hi = value
    if not (low <= lo <= hi <= high):
        raise ValueError(f"{name}: expected {low} <= min <= max <= {high}, got {value}")


@dataclass(frozen=True)
class RaindropsSpec:
    """Drops on the glass, rendered as small spherical-cap lenses.

    Attributes:
        count: number of drops per frame.
        radius_px: drop footprint radius range, pixels.
        aspect: ratio of minor to major axis (1 = round), range.
        contact_angle_deg: angle between glass and drop surface at the rim,
            range; larger angles give stronger lenses.
        refractive_index: of water, 1.33; 1.0 makes the drop invisible.
        persistence: fraction of drops kept from one frame to the next in a
            sequence (real drops stay put while the robot drives).

    """

    count: int = 50
    radius_px: tuple[float, float] = (5.0, 25.0)
    aspect: tuple[float, float] = (0.7, 1.0)
    contact_angle_deg: tuple[float, float] = (30.0, 80.0)
    refractive_index: float = 1.33
    persistence: float = 1.0

    def __post_init__(self) -> None:
        if self.count < 0:
            raise ValueError(f"count: expected >= 0, got {self.count}")
        _check_range("radius_px", self.radius_px, 0.0, 1e4)
        _check_range("aspect", self.aspect, 0.05, 1.0)
        _check_range("contact_angle_deg", self.contact_angle_deg, 0.0, 90.0)
        if not 1.0 <= self.refractive_index <= 3.0:
            raise ValueError(f"refractive_index: expected 1..3, got {self.refractive_index}")
        if not 0.0 <= self.persistence <= 1.0:
            raise ValueError(f"persistence: expected 0..1, got {self.persistence}")


@dataclass(frozen=True)
class DefocusSpec:
    """The glass is out of focus: blur the drop layer.

    Attributes:
        shifts: number of random shifts averaged (the paper's method).
        shift_px: maximum shift, pixels.
        disk_radius_px: optional thin-lens disk blur radius (0 = off).

    """

    shifts: int = 8
    shift_px: float = 3.0
    disk_radius_px: float = 0.0

    def __post_init__(self) -> None:
        if self.shifts < 1:
            raise ValueError(f"shifts: expected >= 1, got {self.shifts}")
        if self.shift_px < 0 or self.disk_radius_px < 0:
            raise ValueError("shift_px and disk_radius_px must be >= 0")


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
        if not 0.0 <= self.fraction <= 1.0:
            raise ValueError(f"fraction: expected 0..1, got {self.fraction}")
        _check_range("gain", self.gain, 0.0, 100.0)


@dataclass(frozen=True)
class DustSpec:
    """Low-frequency attenuation and scattering: ``I = I0 * a + b``.

    Attributes:
        attenuation: range of the darkest transmission ``a`` (1 = clear).
        scatter: largest additive veil ``b`` in linear light.
        scale_px: spatial scale of the smooth fields, pixels.
        coverage: fraction of the image the dust patches cover.

    """

    attenuation: tuple[float, float] = (0.6, 0.9)
    scatter: float = 0.08
    scale_px: float = 80.0
    coverage: float = 0.5

    def __post_init__(self) -> None:
        _check_range("attenuation", self.attenuation, 0.0, 1.0)
        if not 0.0 <= self.scatter <= 1.0:
            raise ValueError(f"scatter: expected 0..1, got {self.scatter}")
        if self.scale_px <= 0:
            raise ValueError(f"scale_px: expected > 0, got {self.scale_px}")
        if not 0.0 <= self.coverage <= 1.0:
            raise ValueError(f"coverage: expected 0..1, got {self.coverage}")


@dataclass(frozen=True)
class DirtSpec:
    """Opaque and semi-transparent blobs of dirt on the glass.

    Attributes:
        count: number of blobs.
        radius_px: blob radius range, pixels.
        opacity: opacity range (1 = opaque).
        color: linear-light grey level of the dirt.

    """

    count: int = 6
    radius_px: tuple[float, float] = (8.0, 40.0)
    opacity: tuple[float, float] = (0.5, 1.0)
    color: float = 0.05

    def __post_init__(self) -> None:
        if self.count < 0:
            raise ValueError(f"count: expected >= 0, got {self.count}")
        _check_range("radius_px", self.radius_px, 0.0, 1e4)
        _check_range("opacity", self.opacity, 0.0, 1.0)
        if not 0.0 <= self.color <= 1.0:
            raise ValueError(f"color: expected 0..1, got {self.color}")


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
