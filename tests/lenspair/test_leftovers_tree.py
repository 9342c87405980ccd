"""remove_leftovers_under: temporaries of dead processes at any depth, nothing else."""

import subprocess
import sys
from pathlib import Path

from lenspair.core.leftovers import remove_leftovers_under
from tests.processes import wait_gone


def test_removes_dead_temporaries_at_any_depth_and_keeps_the_rest(tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    deep = tmp_path / "a" / "b"
    deep.mkdir(parents=True)
    stale = [tmp_path / f".r.json.{dead}.x.tmp", deep / f".01.png.{dead}.y.png.tmp"]
    kept = [deep / "01.png", deep / ".notes.txt"]
    for path in stale + kept:
        path.write_bytes(b"x")
    assert remove_leftovers_under(tmp_path) == 2
    assert not any(path.exists() for path in stale)
    assert all(path.exists() for path in kept)
    assert remove_leftovers_under(tmp_path / "missing") == 0


def test_temporaries_of_an_unreaped_zombie_are_removed(tmp_path: Path) -> None:
    # A killed worker whose parent died too can stay a zombie for good (a
    # container's PID 1 that never reaps); os.kill(pid, 0) still succeeds on it.
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    # ended, not waited for: a zombie (alive() counts zombies as gone)
    assert not wait_gone({child.pid}, timeout=30), "the child never ended"
    assert Path(f"/proc/{child.pid}").exists()
    try:
        stale = tmp_path / f".01.png.{child.pid}.z.png.tmp"
        stale.write_bytes(b"x")
        assert remove_leftovers_under(tmp_path) == 1
        assert not stale.exists()
    finally:
        child.wait()


def test_temporaries_of_a_running_process_are_kept(tmp_path: Path) -> None:
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        busy = tmp_path / f".01.png.{child.pid}.r.png.tmp"
        busy.write_bytes(b"x")
        assert remove_leftovers_under(tmp_path) == 0
        assert busy.exists()
    finally:
        child.kill()
        child.wait()
