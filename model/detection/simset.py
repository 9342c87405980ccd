"""A small simulated multi-kind set of recordings for training and scoring detectors.

:func:`simulate_kind_set` renders, with the scene simulator, ``per_kind``
short recordings of each kind in :data:`SCENE_KINDS` (clean glass, rain,
dust, dirt) from the sample scene ``calib_samples/rain.yaml``: each recording
gets its own seed, its own mix of textures (3 to 9 of them, rotated through
the sample textures: the more textures, the smaller each cell of the
mosaic), its own walking direction and its own obstructed camera (cam0 and
cam1 alternate), so that held-out recordings are new scenes, not
neighbouring frames of a training recording.

The mosaic's cell size (its texture count), the direction and the side of
recording ``k`` are the same for every kind, and ``k = 0`` has the sample
scenes' 9 textures, so none of them predicts the kind: when the texture
count followed the recording's number across kinds, the only 9-texture
training recordings were obstructed ones, and a detector trained on them
called the clean frames of the sample scenes obstructed. Which textures
still follows the number, so every recording is a scene of its own: with
the same scene for recording ``k`` of every kind, a detector learnt the
clean look of each training scene and called every new scene obstructed.
Recordings are named ``<kind>_<k>``; :func:`split_by_recording` puts the
last ``held_out`` of each kind in the test set, the way ``dataset-build``
splits by recording to avoid the leakage of
consecutive frames in both train and test.
"""

import logging
from dataclasses import replace
from pathlib import Path

from lenspair.core.errors import LenspairError
from lenspair.core.fsutil import remove_path
from lenspair.core.samples import sample_path
from lenspair.model.detection.parallel import process_map
from lenspair.simulate.effects.spec import (
    BrightnessSpec,
    DefocusSpec,
    DirtSpec,
    DustSpec,
    EffectsSpec,
    RaindropsSpec,
)
from lenspair.simulate.recording import INCOMPLETE, simulate_recording
from lenspair.simulate.spec import ObstructionSpec, SceneSpec, load_scene

log = logging.getLogger(__name__)

SCENE_KINDS: dict[str, EffectsSpec] = {
    "clean": EffectsSpec(),
    "rain": EffectsSpec(
        raindrops=RaindropsSpec(count=40, radius_px=(6.0, 22.0)),
        defocus=DefocusSpec(shifts=8, shift_px=3.0),
        brightness=BrightnessSpec(fraction=0.3),
    ),
    "dust": EffectsSpec(
        dust=DustSpec(attenuation=(0.55, 0.85), scatter=0.08, scale_px=90.0, coverage=0.6)
    ),
    "dirt": EffectsSpec(dirt=DirtSpec(count=6), defocus=DefocusSpec(shifts=8, shift_px=2.0)),
}
"""Glass effects of each kind of recording (rain as in the sample ``rain.yaml``)."""

_TEXTURES = (
    "astronaut",
    "gravel",
    "coffee",
    "brick",
    "rocket",
    "grass",
    "chelsea",
    "camera",
    "immunohistochemistry",
    "moon",
    "coins",
)


def kind_set_paths(out: Path, per_kind: int = 3) -> list[Path]:
    """The recording folders of :func:`simulate_kind_set`, kind by kind (nothing rendered)."""
    return [Path(out) / f"{kind}_{k}" for kind in SCENE_KINDS for k in range(per_kind)]


def kind_set_specs(
    out: Path, per_kind: int = 3, frames: int = 6, seed: int = 0
) -> list[tuple[Path, SceneSpec]]:
    """The folders and scene specs of :func:`simulate_kind_set`, kind by kind."""
    base = load_scene(sample_path("rain.yaml"))
    specs = []
    for kind_number, effects in enumerate(SCENE_KINDS.values()):
        for k in range(per_kind):
            count = 9 - k % 7  # 9 (the samples' mosaic) down to 3 textures: finer to coarser
            number = kind_number * per_kind + k
            textures = tuple(_TEXTURES[(number + i) % len(_TEXTURES)] for i in range(count))
            planes = tuple(replace(p, texture=textures) for p in base.planes)
            direction = 1.0 if k % 2 else -1.0
            velocity = (direction * 0.8, 0.05 * direction, 0.0)
            spec = replace(
                base,
                planes=planes,
                motion=replace(base.motion, velocity_mps=velocity),
                recording=replace(base.recording, frames=frames, drop_probability=(0.0, 0.0)),
                obstructed=ObstructionSpec(camera="cam1" if k % 2 else "cam0", effects=effects),
                seed=seed + 100 * kind_number + k,
            )
            specs.append(spec)
    return list(zip(kind_set_paths(out, per_kind), specs, strict=True))


def _finished(path: Path, spec: SceneSpec) -> bool:
    """Whether ``path`` holds a complete rendering of ``spec`` (its scene.yaml is the spec)."""
    if (path / INCOMPLETE).exists() or not (path / "rig.yaml").is_file():
        return False
    try:
        return load_scene(path / "scene.yaml") == spec
    except LenspairError:  # missing or unreadable: not a rendering of this spec
        return False


def _simulate(job: tuple[Path, SceneSpec]) -> None:
    path, spec = job
    simulate_recording(spec, path)


def simulate_kind_set(
    out: Path, per_kind: int = 3, frames: int = 6, seed: int = 0, workers: int = 1
) -> list[Path]:
    """Render ``per_kind`` recordings of every kind under ``out/<kind>_<k>/``.

    Finished recordings of the same spec are kept, so a rerun resumes; one
    rendered with other settings (``--set-per-kind``, whose count picks each
    recording's textures, ``--set-frames``, ``--seed``) is rendered
    again (said in the log), since a set mixing both would train on what the
    command line no longer says.

    Args:
        out: output folder.
        per_kind: recordings per kind.
        frames: frames per recording.
        seed: base seed; recording ``k`` of kind ``i`` uses ``seed + 100 i + k``.
        workers: processes rendering recordings side by side (1: in this
            process); the recordings do not depend on it.

    Returns:
        The recording folders, kind by kind.
    """
    jobs = kind_set_specs(out, per_kind, frames, seed)
    todo = [job for job in jobs if not _finished(*job)]
    for path, _ in todo:
        if (path / "scene.yaml").is_file() and not (path / INCOMPLETE).exists():
            log.warning(
                "%s: rendered with other settings (per kind, frames, seed): rendering it again",
                path,
            )
            for child in path.iterdir():
                remove_path(child)
    process_map(_simulate, todo, workers)
    return [path for path, _ in jobs]


def split_by_recording(paths: list[Path], held_out: int = 1) -> tuple[list[Path], list[Path]]:
    """``(train, test)``: the last ``held_out`` recordings of each kind are test."""
    train: list[Path] = []
    test: list[Path] = []
    for path in paths:
        index = int(path.name.rsplit("_", 1)[1])
        per_kind = sum(1 for p in paths if p.name.rsplit("_", 1)[0] == path.name.rsplit("_", 1)[0])
        (test if index >= per_kind - held_out else train).append(path)
    return train, test
