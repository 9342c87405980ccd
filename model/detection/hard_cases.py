"""Hard cases for the detector: augmentations of clean simulated views (issue #14).

The first bundled detector failed on frames that are hard from one image
alone; these samples teach them. Each is made from a *clean view* of a
simulated recording (the clean camera's frame, or the obstructed camera's
``truth/clear`` frame: the same view through clean glass) at the camera's own
resolution, so that effect sizes in pixels mean what they mean in a real
recording (the sample ``rain.yaml`` drops are 6-22 px on a 720x540 frame,
2-8 px at the detector's input size). :data:`HARD_CASES` cycle:

* hard **negatives** (kind ``clean``, empty map): ``defocus`` (a Gaussian
  blur of random sigma, 1-7 px at 720 px width: a focus or motion problem,
  not the glass; then an exposure gain as below), ``exposure`` (a gain of
  0.2-1.6, log-uniform, clipped: dark and over-exposed clean scenes),
  ``flat`` (a low-texture scene: a small part of the view enlarged to the
  whole frame, so sky- or wall-like, with a random gain);
* hard **positives**: ``veiled_dust`` (dust over 80-100 % of the frame with
  patches of a fifth to a third of its width, transmission 0.45-0.9 and
  scatter 0.03-0.12, half of them with a wet-glass veil; it darkens and
  flattens the whole frame smoothly, as the issue's failure case), and
  ``light_rain`` (the drops, defocus and brightening of ``rain.yaml``, 15-60
  drops).

Positives are rendered over a view of one of the negatives' looks (as it
is, defocused, or flat, a third each) with a random exposure gain
(0.3-1.2), so that neither sharpness nor darkness is evidence either way
(with sharp positives only, a detector learned "sharp means obstructed" and
called the sharp clean frames of the sample scene obstructed). Labels: the
kind is the case's; the map is the rendered footprint where the glass visibly changes the view
(:func:`lenspair.model.detection.data.visible_footprint`, no gain
compensation: the clean view has the same exposure); a positive whose
effect happens to be invisible is labelled clean.

Sample ``n`` of a batch is :data:`HARD_CASES` ``[n % 5]``; all random
choices come from the ``rng`` passed, so the same views and seed give the
same samples.
"""

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from lenspair.capture.recording import FrameRef, load_frame, open_recording, resolve_obstructed
from lenspair.core.imageio import read_image
from lenspair.model.detection.data import DetectorSample, labelled, visible_footprint
from lenspair.model.detection.labels import to_luma
from lenspair.model.detection.simset import SCENE_KINDS
from lenspair.model.networks.detector import KINDS, DetectorSpec
from lenspair.simulate.effects.spec import DustSpec, EffectsSpec, VeilSpec
from lenspair.simulate.render import render_effects

HARD_CASES: tuple[str, ...] = ("defocus", "exposure", "flat", "veiled_dust", "light_rain")
"""The cases, in the order samples cycle through them (module docstring)."""

HARD_KINDS: dict[str, str] = {
    "defocus": "clean",
    "exposure": "clean",
    "flat": "clean",
    "veiled_dust": "dust",
    "light_rain": "rain",
}
"""The kind each case is labelled with (before the visibility check of positives)."""

REFERENCE_WIDTH = 720.0
"""Frame width, pixels, that the pixel sizes of the cases refer to (the sample rig)."""

CleanView = FrameRef | Path
"""A clean view: a frame of the clean camera, or a ``truth/clear`` image file."""


def clean_views(recording: Path, max_frames: int | None = None) -> list[CleanView]:
    """The clean views of a simulated recording: clean camera frames and ``truth/clear``.

    Args:
        recording: a ``lenspair simulate`` output folder.
        max_frames: per camera, spread evenly; None: all.
    """
    path = Path(recording)
    opened = open_recording(path)
    obstructed = resolve_obstructed(path).obstructed
    views: list[CleanView] = []
    for camera in ("cam0", "cam1"):
        frames = opened.frames[camera]
        if max_frames is not None and len(frames) > max_frames:
            picks = np.linspace(0, len(frames) - 1, max_frames).round().astype(int)
            frames = [frames[i] for i in sorted(set(picks.tolist()))]
        for frame in frames:
            clear = path / "truth" / "clear" / f"{frame.t_ns}.png"
            if camera != obstructed:
                views.append(frame)
            elif clear.is_file():
                views.append(clear)
    return views


def load_view(view: CleanView) -> np.ndarray:
    """Pixels of a clean view as ``uint8`` luma ``(H, W)``."""
    image = read_image(view) if isinstance(view, Path) else load_frame(view)
    luma = np.round(to_luma(image) * np.float32(255.0))
    return np.asarray(luma, dtype=np.uint8)


def _gain(image: np.ndarray, gain: float) -> np.ndarray:
    scaled = np.clip(image.astype(np.float32) * np.float32(gain), 0.0, 255.0)
    return np.asarray(np.round(scaled), dtype=np.uint8)


def _exposure(rng: np.random.Generator) -> float:
    """A gain of 0.2-1.6, uniform in its logarithm (as many darker as brighter frames)."""
    return float(np.exp(rng.uniform(np.log(0.2), np.log(1.6))))


def defocused(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """``uint8`` ``(H, W)`` blurred with a Gaussian of ``sigma_px``."""
    blurred = np.asarray(cv2.GaussianBlur(image.astype(np.float32), (0, 0), sigma_px))
    return np.round(np.clip(blurred, 0.0, 255.0)).astype(np.uint8)


def flat_scene(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A low-texture scene: an eighth to a quarter of the view enlarged to its size."""
    height, width = image.shape
    share = rng.uniform(0.125, 0.25)
    crop_h, crop_w = max(4, round(height * share)), max(4, round(width * share))
    top = int(rng.integers(0, height - crop_h + 1))
    left = int(rng.integers(0, width - crop_w + 1))
    crop = image[top : top + crop_h, left : left + crop_w]
    enlarged = cv2.resize(crop, (width, height), interpolation=cv2.INTER_CUBIC)
    return np.asarray(enlarged, dtype=np.uint8)


def veiled_dust(width: int, rng: np.random.Generator) -> EffectsSpec:
    """Smooth dust over (nearly) the whole frame, half the time with a veil."""
    low = float(rng.uniform(0.45, 0.7))
    dust = DustSpec(
        attenuation=(low, min(0.9, low + 0.2)),
        scatter=float(rng.uniform(0.03, 0.12)),
        scale_px=float(width * rng.uniform(0.2, 0.33)),
        coverage=float(rng.uniform(0.8, 1.0)),
    )
    veil = VeilSpec(strength=(0.1, 0.3)) if rng.random() < 0.5 else None
    return EffectsSpec(dust=dust, veil=veil)


def light_rain(width: int, rng: np.random.Generator) -> EffectsSpec:
    """The rain of the sample ``rain.yaml`` (drops, defocus, brightening), 15-60 drops."""
    rain = SCENE_KINDS["rain"]
    assert rain.raindrops is not None and rain.defocus is not None  # the sample's rain
    scale = width / REFERENCE_WIDTH
    low, high = rain.raindrops.radius_px
    drops = replace(
        rain.raindrops, count=int(rng.integers(15, 61)), radius_px=(low * scale, high * scale)
    )
    shift = rain.defocus.shift_px
    defocus = replace(rain.defocus, shift_px=None if shift is None else shift * scale)
    return replace(rain, raindrops=drops, defocus=defocus)


def hard_sample(
    view: np.ndarray,
    case: str,
    spec: DetectorSpec,
    rng: np.random.Generator,
    source: str,
    group: str,
) -> DetectorSample:
    """One sample of ``case`` (:data:`HARD_CASES`) made from a clean ``uint8`` ``(H, W)`` view.

    Raises:
        KeyError: an unknown case.
    """
    kind = HARD_KINDS[case]
    scale = view.shape[1] / REFERENCE_WIDTH
    if case == "defocus":
        blurred = _gain(defocused(view, scale * rng.uniform(1.0, 7.0)), _exposure(rng))
        return labelled(blurred, 0, None, spec, source, group)
    if case == "exposure":
        return labelled(_gain(view, _exposure(rng)), 0, None, spec, source, group)
    if case == "flat":
        flat = _gain(flat_scene(view, rng), float(rng.uniform(0.3, 1.3)))
        return labelled(flat, 0, None, spec, source, group)
    look = int(rng.integers(3))  # the negatives' looks, so that blur is no evidence either
    if look == 1:
        view = defocused(view, scale * rng.uniform(1.0, 7.0))
    elif look == 2:
        view = flat_scene(view, rng)
    base = _gain(view, float(rng.uniform(0.3, 1.2)))
    effects = veiled_dust if case == "veiled_dust" else light_rain
    obstructed, footprint = render_effects(base, effects(view.shape[1], rng), rng)
    mask = visible_footprint(obstructed, base, footprint)
    kind_id = KINDS.index(kind) if mask.any() else 0
    return labelled(obstructed, kind_id, mask, spec, source, group)


def hard_samples(
    views: Sequence[CleanView],
    count: int,
    spec: DetectorSpec,
    rng: np.random.Generator,
    group: str = "synthetic",
    first: int = 0,
) -> list[DetectorSample]:
    """``count`` hard cases over randomly picked clean views (module docstring).

    Args:
        views: clean views to draw from (:func:`clean_views`).
        count: samples to make; case of sample ``n`` is ``HARD_CASES[n % 5]``.
        spec: the detector's architecture (input size).
        rng: all random choices.
        group: group name of the samples (``synthetic`` shares the synthetic
            half of each batch, see :func:`lenspair.model.detection.train.sampling_weights`).
        first: number of the first sample (cases and source names continue from it).

    Raises:
        ValueError: no view to draw from.
    """
    if not views:
        raise ValueError("hard cases need at least one clean view")
    samples = []
    for number in range(first, first + count):
        case = HARD_CASES[number % len(HARD_CASES)]
        view = load_view(views[int(rng.integers(len(views)))])
        samples.append(hard_sample(view, case, spec, rng, f"hard:{case}:{number}", group))
    return samples
