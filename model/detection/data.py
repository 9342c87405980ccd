"""Training and scoring samples for the detector, from three sources.

Every sample is one grey frame resized to the detector's input size with its
labels (:class:`DetectorSample`):

* **lenspair datasets** (:func:`dataset_samples`): each manifest row of the
  split gives a positive (``input/``, the obstructed view; kind from the
  row's anomaly labels, :func:`dataset_kind`; map from the registered pair
  by the rule of :func:`lenspair.model.detection.labels.pair_anomaly_mask`)
  and a negative (``target/``, the clean view; empty map). Pairs that
  ``dataset-build`` marked ``clean`` (the views barely differ) give two
  negatives: the glass did not visibly disturb that frame, and calling it
  obstructed would teach the detector to see anomalies where there are none.
  The difficulty, not the labels, decides obstructed or clean: a pair
  without labels (``capture-ingest --obstructed`` without ``rig.yaml``) or
  with none this detector knows is a positive of :data:`UNKNOWN_KIND`.
* **simulated recordings** (:func:`recording_samples`, ``lenspair simulate``
  output): the obstructed camera's frames with their exact ``truth/mask/``
  footprint and the kind from ``rig.yaml``, and the clean camera's frames.
  The footprint of dust is the whole support of a smooth field, mostly so
  faint that nothing is visible; the map is therefore the *visible*
  footprint: ``truth/mask`` intersected with the pair rule applied to the
  frame and ``truth/clear`` (the same view through clean glass, same
  exposure, so no gain compensation) at a low threshold (5 % relative change).
* **synthetic anomalies over clean images** (:func:`synthetic_samples`): the
  simulator's renderer puts rain, dust or dirt with random parameters over
  clean images (visible footprints, as above), a quarter of them left clean; before that,
  each clean image gets a random exposure gain and, for some, a defocus blur,
  so that dark and blurry clean scenes are seen as clean.

Images are luma ``float32`` ``(H, W)`` in ``[0, 1]`` (the encoded values);
maps are ``float32`` ``(rows, cols)`` in ``{0, 1}`` with a ``bool`` validity map.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lenspair.capture.recording import open_recording, resolve_obstructed
from lenspair.core.imageio import read_image
from lenspair.dataset.manifest import read_manifest
from lenspair.model.detection.labels import (
    kind_index,
    pair_anomaly_mask,
    tile_truth,
    tile_valid,
    to_luma,
)
from lenspair.model.errors import ModelError
from lenspair.model.networks.detector import KINDS, DetectorSpec
from lenspair.simulate.effects.spec import (
    BrightnessSpec,
    DefocusSpec,
    DirtSpec,
    DustSpec,
    EffectsSpec,
    RaindropsSpec,
)
from lenspair.simulate.render import render_effects
from lenspair.simulate.textures import NAMES

UNKNOWN_KIND = -1
"""Kind index of a positive whose anomaly label is not one of :data:`KINDS`."""


@dataclass(frozen=True)
class DetectorSample:
    """One labelled frame.

    Attributes:
        image: luma ``float32`` ``(H, W)`` in ``[0, 1]`` at the detector's input size.
        kind: index into :data:`KINDS` (0 = clean), or :data:`UNKNOWN_KIND`.
        tiles: ``float32`` ``(rows, cols)``, 1 where the glass is covered.
        valid: ``bool`` ``(rows, cols)``, tiles that count in the map loss and IoU.
        source: where it came from (file, or ``synthetic:<n>``), for reports.
        group: the recording (or split group) it belongs to.
    """

    image: np.ndarray
    kind: int
    tiles: np.ndarray
    valid: np.ndarray
    source: str
    group: str

    @property
    def obstructed(self) -> bool:
        """True unless the sample is clean."""
        return self.kind != 0


def resize_to(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize ``(H, W)`` to ``size = (height, width)`` with area averaging (no-op if equal)."""
    height, width = size
    if image.shape[:2] == (height, width):
        return image
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def prepare(image: np.ndarray, spec: DetectorSpec) -> np.ndarray:
    """Any ``uint8``/``uint16`` image -> luma ``float32`` at ``spec.input_size``."""
    return resize_to(to_luma(image), spec.input_size)


def _mask_at(mask: np.ndarray, spec: DetectorSpec) -> np.ndarray:
    covered = resize_to((np.asarray(mask) > 0).astype(np.float32), spec.input_size)
    return covered >= 0.5


VISIBLE_THRESHOLD = 0.05
"""Relative change above which a footprint pixel is visible (module docstring)."""


def visible_footprint(obstructed: np.ndarray, clear: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``bool`` ``(H, W)``: footprint pixels where the glass visibly changes the view.

    ``clear`` must have the exposure of ``obstructed`` (no gain compensation:
    dust that darkens the whole frame evenly is visible, not an exposure change).
    """
    changed = pair_anomaly_mask(
        obstructed, clear, threshold=VISIBLE_THRESHOLD, compensate_gain=False
    )
    covered: np.ndarray = (np.asarray(mask) > 0) & changed
    return covered


def labelled(
    image: np.ndarray,
    kind: int,
    mask: np.ndarray | None,
    spec: DetectorSpec,
    source: str,
    group: str,
    untrusted: np.ndarray | None = None,
) -> DetectorSample:
    """A sample from an image and its covered-pixel mask (None: nothing covered)."""
    grid = spec.grid
    tiles = np.zeros(grid, np.float32)
    if mask is not None and kind != 0:
        tiles = tile_truth(_mask_at(mask, spec), grid).astype(np.float32)
    valid = tile_valid(None if untrusted is None else _mask_at(untrusted, spec), grid)
    return DetectorSample(prepare(image, spec), kind, tiles, valid, source, group)


def dataset_kind(difficulty: str, labels: Sequence[str]) -> int:
    """Kind of a dataset pair's input view: index into :data:`KINDS`, or :data:`UNKNOWN_KIND`.

    ``dataset-build`` tags a pair ``clean`` when its views barely differ and
    ``easy``/``medium``/``hard`` when the glass visibly disturbs the input, so
    the difficulty decides obstructed or clean and the labels only name the
    kind. A disturbed input without labels (``capture-ingest --obstructed``
    without ``rig.yaml`` writes ``"anomaly": []``), or whose labels name no
    known anomaly, is still obstructed: :data:`UNKNOWN_KIND`, never clean.
    """
    if difficulty == "clean":
        return 0
    kind = kind_index(labels)
    return UNKNOWN_KIND if kind is None or kind == 0 else kind


def dataset_samples(root: Path, split: str, spec: DetectorSpec) -> list[DetectorSample]:
    """Positives and negatives of one split of a lenspair dataset (module docstring).

    Raises:
        ModelError: no ``manifest.jsonl`` or no row in ``split``.
        ImageIOError: an unreadable image (names the file).
    """
    root = Path(root)
    manifest = root / "manifest.jsonl"
    if not manifest.is_file():
        raise ModelError(f"{root}: not a lenspair dataset (no manifest.jsonl)")
    rows = [row for row in read_manifest(manifest) if row.split == split]
    if not rows:
        raise ModelError(f"{manifest}: no pairs in split {split!r}")
    samples = []
    for row in rows:
        files = {key: root / value for key, value in row.files.items()}
        seen = read_image(files.get("input", root / split / "input" / f"{row.name}.png"))
        clean = read_image(files.get("target", root / split / "target" / f"{row.name}.png"))
        untrusted = read_image(files["mask"]) if "mask" in files else None
        if untrusted is not None and untrusted.ndim == 3:
            untrusted = untrusted[:, :, 0]
        if seen.shape[:2] != clean.shape[:2]:  # a damaged dataset: said, not a traceback
            raise ModelError(
                f"{files.get('input', row.name)}: {seen.shape[1]}x{seen.shape[0]} pixels, its "
                f"target {clean.shape[1]}x{clean.shape[0]}; check it with dataset-build --verify"
            )
        kind = dataset_kind(row.difficulty, row.anomaly)
        covered = pair_anomaly_mask(seen, clean, untrusted) if kind != 0 else None
        name = f"{split}/{row.name}"
        samples.append(labelled(seen, kind, covered, spec, f"{name}:input", row.group, untrusted))
        samples.append(labelled(clean, 0, None, spec, f"{name}:target", row.group, untrusted))
    return samples


def recording_samples(
    path: Path, spec: DetectorSpec, max_frames: int | None = None
) -> list[DetectorSample]:
    """Both cameras of a simulated recording, labelled from ``rig.yaml`` and ``truth/mask/``.

    Args:
        path: a ``lenspair simulate`` output folder.
        spec: the detector's architecture (input size).
        max_frames: per camera, spread evenly over the recording; None: all.

    Raises:
        ModelError: no ``truth/mask/`` (not a simulated recording).
        CaptureError: unreadable recording or ``rig.yaml``.
    """
    path = Path(path)
    masks = path / "truth" / "mask"
    if not path.is_dir():
        raise ModelError(f"{path}: no such recording folder")
    if not masks.is_dir():
        raise ModelError(f"{path}: no truth/mask/ (train on real recordings via dataset-build)")
    recording = open_recording(path)
    rig = resolve_obstructed(path)
    kind = kind_index(rig.anomaly)
    kind = UNKNOWN_KIND if kind is None else kind
    samples = []
    for camera in ("cam0", "cam1"):
        frames = recording.frames[camera]
        if max_frames is not None and len(frames) > max_frames:
            picks = np.linspace(0, len(frames) - 1, max_frames).round().astype(int)
            frames = [frames[i] for i in sorted(set(picks.tolist()))]
        for frame in frames:
            image = recording.load(frame)
            source = f"{recording.recording_id}/{camera}/{frame.t_ns}"
            if camera == rig.obstructed:
                mask = read_image(masks / f"{frame.t_ns}.png")
                if mask.shape[:2] != image.shape[:2]:
                    raise ModelError(
                        f"{masks / f'{frame.t_ns}.png'}: {mask.shape[1]}x{mask.shape[0]} pixels, "
                        f"its frame {image.shape[1]}x{image.shape[0]} (not this recording's truth)"
                    )
                clear_file = path / "truth" / "clear" / f"{frame.t_ns}.png"
                if clear_file.is_file():
                    mask = visible_footprint(image, read_image(clear_file), mask)
                frame_kind = kind if mask.any() or kind == 0 else 0
                samples.append(
                    labelled(image, frame_kind, mask, spec, source, recording.recording_id)
                )
            else:
                samples.append(labelled(image, 0, None, spec, source, recording.recording_id))
    return samples


def random_effects(kind: str, rng: np.random.Generator) -> EffectsSpec:
    """Effects of one kind with random strength, for synthetic samples.

    Raises:
        ModelError: ``kind`` is ``clean`` or unknown.
    """
    if kind == "rain":
        return EffectsSpec(
            raindrops=RaindropsSpec(count=int(rng.integers(8, 70)), radius_px=(4.0, 24.0)),
            defocus=DefocusSpec(shift_px=float(rng.uniform(1.0, 4.0))),
            brightness=BrightnessSpec(),
        )
    if kind == "dust":
        low = float(rng.uniform(0.45, 0.8))
        return EffectsSpec(
            dust=DustSpec(
                attenuation=(low, min(0.95, low + 0.25)),
                scatter=float(rng.uniform(0.02, 0.12)),
                scale_px=float(rng.uniform(50.0, 160.0)),
                coverage=float(rng.uniform(0.3, 1.0)),
            )
        )
    if kind == "dirt":
        return EffectsSpec(
            dirt=DirtSpec(count=int(rng.integers(2, 10))),
            defocus=DefocusSpec(shift_px=float(rng.uniform(1.0, 4.0))),
        )
    raise ModelError(f"no effects for kind {kind!r}; valid: rain, dust, dirt")


MIN_CLEAN_SIDE = 16
"""Smallest side of a clean image that synthetic samples are cut from, pixels."""


def _random_view(image: np.ndarray, spec: DetectorSpec, rng: np.random.Generator) -> np.ndarray:
    """A random crop of ``image`` (at least half its size) resized to the input size."""
    height, width = image.shape[:2]
    target_h, target_w = spec.input_size
    scale = rng.uniform(0.5, 1.0)
    crop_w = max(MIN_CLEAN_SIDE, min(width, round(width * scale)))
    crop_h = max(MIN_CLEAN_SIDE, min(height, round(crop_w * target_h / target_w)))
    top = int(rng.integers(0, height - crop_h + 1))
    left = int(rng.integers(0, width - crop_w + 1))
    crop = image[top : top + crop_h, left : left + crop_w]
    return cv2.resize(crop, (target_w, target_h), interpolation=cv2.INTER_AREA)


def _disturb_clean(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random exposure gain (0.2..1.3) and, for a third of the images, defocus blur."""
    values = image.astype(np.float32) / np.float32(255.0)
    if rng.random() < 1 / 3:
        values = np.asarray(
            cv2.GaussianBlur(values, (0, 0), float(rng.uniform(1.0, 6.0))), np.float32
        )
    scaled = np.clip(values * np.float32(rng.uniform(0.2, 1.3)), 0.0, 1.0)
    disturbed: np.ndarray = np.round(scaled * 255.0).astype(np.uint8)
    return disturbed


def synthetic_samples(
    clean_images: Sequence[np.ndarray],
    count: int,
    spec: DetectorSpec,
    rng: np.random.Generator,
    group: str = "synthetic",
    first: int = 0,
) -> list[DetectorSample]:
    """Rain, dust, dirt and clean frames rendered over clean images (module docstring).

    Args:
        clean_images: ``uint8`` ``(H, W)`` or ``(H, W, 3)`` clean views.
        count: samples to make; kinds cycle clean, rain, dust, dirt.
        spec: the detector's architecture (input size).
        rng: all random choices.
        group: group name of the samples.
        first: number of the first sample (kinds and source names continue from it).

    Raises:
        ModelError: no clean image.
    """
    if not clean_images:
        raise ModelError("synthetic samples need at least one clean image")
    samples = []
    for index in range(first, first + count):
        base = clean_images[int(rng.integers(len(clean_images)))]
        if base.dtype != np.uint8:
            base = (base.astype(np.float32) / 257.0).round().astype(np.uint8)
        view = _disturb_clean(_random_view(base, spec, rng), rng)
        kind = KINDS[index % len(KINDS)]
        if kind == "clean":
            samples.append(labelled(view, 0, None, spec, f"synthetic:{index}", group))
            continue
        obstructed, footprint = render_effects(view, random_effects(kind, rng), rng)
        mask = visible_footprint(obstructed, view, footprint)
        kind_id = KINDS.index(kind) if mask.any() else 0
        samples.append(labelled(obstructed, kind_id, mask, spec, f"synthetic:{index}", group))
    return samples


def texture_images(names: Sequence[str] | None = None) -> list[np.ndarray]:
    """The simulator's built-in scikit-image textures as ``uint8`` images (clean scenes)."""
    chosen = list(names) if names is not None else sorted(NAMES)
    images = []
    for name in chosen:
        raw = np.asarray(NAMES[name]())
        if raw.ndim == 3:
            raw = raw[:, :, :3]
        if raw.dtype != np.uint8:
            raw = (255.0 * raw.astype(np.float64) / max(1.0, float(raw.max()))).astype(np.uint8)
        images.append(np.ascontiguousarray(raw))
    return images
