"""The simulated multi-kind set: scene variety, names, and the split by recording."""

from pathlib import Path

import pytest

from lenspair.model.detection.simset import (
    SCENE_KINDS,
    kind_set_specs,
    simulate_kind_set,
    split_by_recording,
)


def test_scenes_vary_in_textures_side_and_seed(tmp_path: Path) -> None:
    jobs = kind_set_specs(tmp_path, per_kind=7, frames=2, seed=5)
    names = [path.name for path, _ in jobs]
    assert names == [f"{kind}_{k}" for kind in SCENE_KINDS for k in range(7)]
    counts = {len(spec.planes[0].texture) for _, spec in jobs}
    assert counts == set(range(3, 10))  # mosaics as coarse as 3 cells and as fine as the samples' 9
    assert {spec.obstructed.camera for _, spec in jobs} == {"cam0", "cam1"}
    assert len({spec.seed for _, spec in jobs}) == len(jobs)
    assert all(spec.recording.frames == 2 for _, spec in jobs)


def test_the_last_recording_of_each_kind_is_held_out(tmp_path: Path) -> None:
    paths = [path for path, _ in kind_set_specs(tmp_path, per_kind=3)]
    train, test = split_by_recording(paths)
    assert [p.name for p in test] == [f"{kind}_2" for kind in SCENE_KINDS]
    assert len(train) == 8


def test_scene_is_independent_of_kind(tmp_path: Path) -> None:
    """Recording k of every kind has the same mosaic cell size, direction and side, so none
    predicts the kind (k = 0: the sample scenes' 9 textures, so clean glass is seen on it);
    the textures differ, so no scene is seen under every kind of glass."""
    jobs = kind_set_specs(tmp_path, per_kind=5)
    looks: dict[str, list[tuple[object, ...]]] = {}
    for path, spec in jobs:
        kind = path.name.rsplit("_", 1)[0]
        look = (len(spec.planes[0].texture), spec.motion.velocity_mps, spec.obstructed.camera)
        looks.setdefault(kind, []).append(look)
    assert all(kind_looks == looks["clean"] for kind_looks in looks.values())
    assert len(set(looks["clean"])) == 5 and looks["clean"][0][0] == 9
    assert len({spec.planes[0].texture for _, spec in jobs}) == len(jobs)


def test_a_rerun_with_other_frames_or_seed_renders_again_and_one_alike_resumes(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The set was reused whatever --set-frames and --seed said: training on the old one."""
    from lenspair.simulate.spec import load_scene

    out = tmp_path / "set"
    (first,) = [p for p in simulate_kind_set(out, per_kind=1, frames=1) if p.name == "rain_0"]
    stamp = (first / "rig.yaml").stat().st_mtime_ns
    simulate_kind_set(out, per_kind=1, frames=1)  # the same: kept
    assert (first / "rig.yaml").stat().st_mtime_ns == stamp
    with caplog.at_level("WARNING"):
        simulate_kind_set(out, per_kind=1, frames=2, seed=5)
    assert load_scene(first / "scene.yaml").recording.frames == 2
    assert load_scene(first / "scene.yaml").seed == 105  # seed + 100 x kind number
    assert len(list((first / "mav0" / "cam0" / "data").glob("*.png"))) == 2
    assert sum("rendering it again" in m for m in caplog.messages) == 4  # every kind
    # the count per kind picks each recording's textures: it was left out of what is said
    assert all("(per kind, frames, seed)" in m for m in caplog.messages if "again" in m)
