"""remove_leftovers_under: temporaries of dead processes at any depth, nothing else."""

import os
import subprocess
import sys
from pathlib import Path

from lenspair.core.fsutil import temporary_folder
from lenspair.core.leftovers import leftovers, remove_leftovers_under
from tests.processes import dead_pid, wait_gone


def test_removes_dead_temporaries_at_any_depth_and_keeps_the_rest(tmp_path: Path) -> None:
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    deep = tmp_path / "a" / "b"
    deep.mkdir(parents=True)
    stale = [tmp_path / f".r.json.{dead}.xxxxxxxx.tmp", deep / f".01.png.{dead}.yyyyyyyy.png.tmp"]
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
        stale = tmp_path / f".01.png.{child.pid}.zzzzzzzz.png.tmp"
        stale.write_bytes(b"x")
        assert remove_leftovers_under(tmp_path) == 1
        assert not stale.exists()
    finally:
        child.wait()


def test_temporaries_of_a_running_process_are_kept(tmp_path: Path) -> None:
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        busy = tmp_path / f".01.png.{child.pid}.rrrrrrrr.png.tmp"
        busy.write_bytes(b"x")
        assert remove_leftovers_under(tmp_path) == 0
        assert busy.exists()
    finally:
        child.kill()
        child.wait()


def test_a_live_build_of_a_sibling_named_with_a_number_is_not_a_leftover(tmp_path: Path) -> None:
    # building DS removed the live `.DS.<n>.<pid>.<random>.building` of `DS.<n>`: it read the
    # number n as the process that made it, and that one was gone
    gone = dead_pid()
    live = temporary_folder(tmp_path, f"DS.{gone}", ".building")  # this process's: alive
    live_file = tmp_path / f".DS.{gone}.{os.getpid()}.abcd1234.png.tmp"
    live_file.write_bytes(b"x")
    assert leftovers(tmp_path, "DS") == [] and leftovers(tmp_path) == []
    dead = tmp_path / f".DS.{gone}.{gone}.abcd1234.building"  # its own, killed: still found
    dead.mkdir()
    assert leftovers(tmp_path, f"DS.{gone}") == [dead] and leftovers(tmp_path) == [dead]
    assert live.is_dir()
