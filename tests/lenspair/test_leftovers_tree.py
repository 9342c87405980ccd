"""remove_leftovers_under: temporaries of dead processes at any depth, nothing else."""

import subprocess
import sys
from pathlib import Path

from lenspair.core.leftovers import remove_leftovers_under


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
