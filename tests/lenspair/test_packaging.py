"""Packaging: one import name, every package listed, samples shipped, demo from anywhere."""

import os
import subprocess
import sys
import sysconfig
import tarfile
import tomllib
import venv
import zipfile
from pathlib import Path

import pytest

from lenspair.core.samples import sample_names, sample_path

ROOT = Path(__file__).resolve().parents[2]


def _setuptools_config() -> dict[str, object]:
    with (ROOT / "pyproject.toml").open("rb") as handle:
        return dict(tomllib.load(handle)["tool"]["setuptools"])


def test_every_package_folder_is_listed_under_lenspair() -> None:
    config = _setuptools_config()
    package_dir: dict[str, str] = config["package-dir"]  # type: ignore[assignment]
    listed = set(config["packages"])  # type: ignore[call-overload]
    found = set()
    for name, folder in package_dir.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            relative = init.parent.relative_to(ROOT / folder)
            found.add(".".join([name, *relative.parts]) if relative.parts else name)
    assert found <= listed, f"packages missing from pyproject.toml: {sorted(found - listed)}"
    assert all(name == "lenspair" or name.startswith("lenspair.") for name in listed)


def test_samples_are_found_as_package_data() -> None:
    names = sample_names()
    assert {"rain.yaml", "chessboard.yaml", "alphasense_camchain.yaml"} <= set(names)
    assert (
        sample_path("rain.yaml").read_text() == (ROOT / "calib_samples" / "rain.yaml").read_text()
    )


def test_unknown_sample_names_the_available_ones() -> None:
    from lenspair.core.errors import LenspairError

    with pytest.raises(LenspairError, match=r"available: .*rain\.yaml"):
        sample_path("no_such_scene.yaml")


def _run(cmd: list[str], cwd: Path, env: dict[str, str] | None = None) -> str:
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, check=False)
    assert done.returncode == 0, f"{cmd} failed:\n{done.stdout}\n{done.stderr}"
    return done.stdout + done.stderr


@pytest.mark.slow
def test_sdist_wheel_installs_one_name_and_demo_runs_from_any_folder(tmp_path: Path) -> None:
    """sdist -> wheel -> fresh venv (offline: dependencies reused) -> demo --quick elsewhere."""
    dist = tmp_path / "dist"
    _run(
        [
            sys.executable,
            "-c",
            f"from setuptools import build_meta as b; b.build_sdist({str(dist)!r})",
        ],
        cwd=ROOT,
    )
    (sdist,) = dist.glob("lenspair-*.tar.gz")
    with tarfile.open(sdist) as archive:
        in_sdist = archive.getnames()
    # setuptools added tests/test_*.py without the helpers they import: they could not run
    assert not [name for name in in_sdist if "/tests/" in name or "/benchmarks/" in name]
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            "-w",
            str(dist),
            str(sdist),
        ],
        cwd=tmp_path,
    )
    (wheel,) = dist.glob("lenspair-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
    top = {name.split("/")[0] for name in names}
    assert {t for t in top if not t.endswith(".dist-info")} == {"lenspair"}
    assert "lenspair/calib_samples/rain.yaml" in names
    assert "lenspair/capture/ingest.py" in names
    assert "lenspair/model/weights/gea_ours_mono.pt" in names  # --init pretrained works installed
    assert "lenspair/py.typed" in names  # Restorer & co. are typed for a user's mypy
    assert any(name.endswith(".dist-info/licenses/LICENSE") for name in names)

    env_dir = tmp_path / "venv"
    venv.create(env_dir, with_pip=False)
    python = env_dir / "bin" / "python"
    target = Path(
        _run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], tmp_path
        ).strip()
    )
    # Offline: the dependencies are the ones this interpreter already has. A path
    # added by a .pth file does not process that folder's own .pth files, so the
    # editable install of the checkout stays invisible to the new environment.
    (target / "deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "-q",
            "--no-deps",
            "--no-index",
            str(wheel),
        ],
        cwd=tmp_path,
    )
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in {"PYTHONPATH"}}
    lenspair = str(env_dir / "bin" / "lenspair")
    where = _run([str(python), "-c", "import lenspair.capture as c; print(c.__file__)"], work, env)
    assert str(target) in where
    assert _run([lenspair, "--version"], work, env).startswith("lenspair ")
    output = _run([lenspair, "demo", "--quick"], work, env)
    assert f"writing to {work / 'demo_out'}" in output
    assert (work / "demo_out" / "report.md").is_file()
