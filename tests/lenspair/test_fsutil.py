"""Atomic writes: all or nothing, and the permissions a plain write would give."""

import errno
import os
import shutil
import stat
from pathlib import Path

import numpy as np
import pytest

from lenspair.core.fsutil import (
    atomic_write,
    atomic_write_text,
    atomic_write_texts,
    check_writable,
    clone_file,
    inside_refusal,
    naming_errors,
    remove_path,
    temporary_folder,
)
from lenspair.core.imagewrite import write_image
from tests.file_limits import REFUSALS, file_size_limit, refuse_writes


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_written_files_get_the_mode_of_a_plain_write(tmp_path: Path) -> None:
    plain = tmp_path / "plain.txt"
    plain.write_text("x")  # open() applies the umask to 0o666
    atomic_write_text(tmp_path / "a" / "report.json", "{}\n")
    write_image(tmp_path / "b" / "frame.png", np.zeros((4, 6), np.uint8))
    assert _mode(tmp_path / "a" / "report.json") == _mode(plain)
    assert _mode(tmp_path / "b" / "frame.png") == _mode(plain)


def test_a_failing_writer_leaves_neither_file_nor_temporary(tmp_path: Path) -> None:
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")

    def broken(tmp: Path) -> None:
        tmp.write_bytes(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write(target, broken)
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]


def test_the_data_reaches_the_disk_before_the_rename(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    events: list[tuple[str, str]] = []
    fsync, replace = os.fsync, os.replace

    def record_fsync(fd: int) -> None:
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        fsync(fd)

    def record_replace(source: str, destination: str) -> None:
        events.append(("replace", str(source)))
        replace(source, destination)

    monkeypatch.setattr(os, "fsync", record_fsync)
    monkeypatch.setattr(os, "replace", record_replace)
    atomic_write_text(tmp_path / "report.json", "{}\n")
    assert [kind for kind, _ in events] == ["fsync", "replace"]
    assert events[0][1] == events[1][1]  # the temporary synced is the one renamed
    # image frames are not synced one by one: their stages check them on a rerun
    events.clear()
    write_image(tmp_path / "frame.png", np.zeros((4, 6), np.uint8))
    assert [kind for kind, _ in events] == ["replace"]


def test_remove_path_takes_files_folders_and_links_but_never_what_a_link_points_to(
    tmp_path: Path,
) -> None:
    kept = tmp_path / "kept"
    (kept / "sub").mkdir(parents=True)
    (kept / "sub" / "x.txt").write_text("x")
    link = tmp_path / "link"
    link.symlink_to(kept, target_is_directory=True)
    remove_path(link)
    assert not link.exists() and (kept / "sub" / "x.txt").is_file()
    remove_path(kept / "sub" / "x.txt")
    assert not (kept / "sub" / "x.txt").exists()
    remove_path(kept)
    assert not kept.exists()
    remove_path(tmp_path / "absent")  # nothing to do, no error


def test_an_out_folder_inside_its_input_is_refused_also_through_a_link(tmp_path: Path) -> None:
    source = tmp_path / "photos"
    (source / "sub").mkdir(parents=True)
    link = tmp_path / "link"
    link.symlink_to(source)
    for out in (source, source / "sub" / "new", link / "restored"):
        problem = inside_refusal(out, source, "the input", "outputs keep its names")
        assert problem is not None and problem.startswith(f"--out {out}: inside the input ")
    # beside the input, a prefix of its name, or an input that is a file: fine
    assert inside_refusal(tmp_path / "photos_out", source, "the input", "x") is None
    image = tmp_path / "one.png"
    image.write_bytes(b"")
    assert inside_refusal(tmp_path, image, "the input", "x") is None


@pytest.mark.parametrize("name", ["x" * 235 + ".png", "ü" * 118 + ".png"])
def test_a_name_near_the_file_system_s_limit_is_written_and_its_leftover_found(
    tmp_path: Path, name: str
) -> None:
    """The temporary added about 25 bytes to a valid 239-byte name: nothing could be written."""
    from lenspair.core.leftovers import leftovers, temporary_prefix

    assert len(os.fsencode(name)) <= 255
    seen: list[str] = []

    def writer(tmp: Path) -> None:
        seen.append(tmp.name)
        tmp.write_bytes(b"frame")

    atomic_write(tmp_path / name, writer)
    assert (tmp_path / name).read_bytes() == b"frame"
    assert len(os.fsencode(seen[0])) <= 255
    # a killed run's temporary of that output, by a process that is gone, is found by name
    dead = tmp_path / seen[0].replace(f".{os.getpid()}.", ".999999999.")
    dead.write_bytes(b"half")
    # another long name cut to the same start: its temporaries are not this output's
    twin = name[:-5] + "2.png"
    other = (
        tmp_path
        / f"{temporary_prefix(twin).replace(f'.{os.getpid()}.', '.999999999.')}a1234567.tmp"
    )
    other.write_bytes(b"half")
    assert leftovers(tmp_path, name) == [dead]
    assert leftovers(tmp_path, twin) == [other]


@pytest.mark.parametrize("code", REFUSALS)
def test_a_refused_write_names_the_user_s_path_not_a_temporary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, code: int
) -> None:
    """They named ``.c.yaml.<pid>.<random>.tmp`` and ``.ds.<pid>.<random>.building``."""
    folder = tmp_path / "mounted"
    folder.mkdir()
    refuse_writes(monkeypatch, folder, code)
    deeper = folder / "new" / "deeper" / "ds"  # folders still to be made: the same name
    for write, named in (
        (lambda: atomic_write_text(folder / "c.yaml", "x\n"), folder / "c.yaml"),
        (lambda: temporary_folder(folder, "ds", ".building"), folder / "ds"),
        (lambda: check_writable(folder / "c.yaml"), folder / "c.yaml"),
        (lambda: check_writable(deeper), deeper),
    ):
        with pytest.raises(OSError) as caught:
            write()
        assert (caught.value.errno, caught.value.strerror) == (code, os.strerror(code))
        assert (caught.value.filename, caught.value.filename2) == (str(named), None)
    assert list(folder.iterdir()) == []


@pytest.mark.parametrize("refused", ["first", "second"])
def test_files_written_together_are_all_replaced_or_none(tmp_path: Path, refused: str) -> None:
    product, report = tmp_path / "camchain.yaml", tmp_path / "camchain.report.json"
    product.write_text("earlier\n")
    report.write_text("earlier report\n")
    small, large = "x" * 100, "y" * 4000
    texts = (
        {report: large, product: small} if refused == "first" else {report: small, product: large}
    )
    with file_size_limit(1024), pytest.raises(OSError) as caught:
        atomic_write_texts(texts)
    named = report if refused == "first" else product
    assert (caught.value.errno, caught.value.filename) == (errno.EFBIG, str(named))
    assert (product.read_text(), report.read_text()) == ("earlier\n", "earlier report\n")
    assert sorted(tmp_path.iterdir()) == sorted([product, report])  # no temporary left
    # a folder where the product goes: refused before the report is replaced
    (tmp_path / "blocked").mkdir()
    with pytest.raises(IsADirectoryError):
        atomic_write_texts({report: "newer\n", tmp_path / "blocked": "x\n"})
    assert report.read_text() == "earlier report\n"
    assert sorted(tmp_path.iterdir()) == sorted([product, report, tmp_path / "blocked"])
    (tmp_path / "blocked").rmdir()
    atomic_write_texts({report: "new report\n", product: "new\n"})
    assert (product.read_text(), report.read_text()) == ("new\n", "new report\n")
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    assert _mode(product) == _mode(report) == _mode(plain)


def test_check_writable_leaves_nothing_and_makes_no_folder(tmp_path: Path) -> None:
    check_writable(tmp_path / "c.yaml")
    check_writable(tmp_path / "new" / "deeper" / "ds")
    (tmp_path / "afile").write_text("x")
    check_writable(tmp_path / "afile" / "c.yaml")  # a file where a folder goes: said later
    assert [p.name for p in tmp_path.iterdir()] == ["afile"]


def test_a_file_too_large_names_its_final_path_also_inside_a_folder_being_built(
    tmp_path: Path,
) -> None:
    """A copy cut short named ``source -> .DS.<pid>.<random>.building/train/input/x.png``."""
    source = tmp_path / "source.png"
    source.write_bytes(bytes(4096))
    out = tmp_path / "DS"
    temp = temporary_folder(tmp_path, out.name, ".building")
    (temp / "train").mkdir()
    with file_size_limit(1024), pytest.raises(OSError) as caught:
        atomic_write(tmp_path / "copy.png", lambda tmp: shutil.copyfile(source, tmp))
    assert (caught.value.errno, caught.value.filename) == (errno.EFBIG, str(tmp_path / "copy.png"))
    assert caught.value.filename2 is None
    with file_size_limit(1024), pytest.raises(OSError) as caught, naming_errors(out):
        clone_file(source, temp / "train" / "x.png")
    assert (caught.value.errno, caught.value.strerror) == (errno.EFBIG, os.strerror(errno.EFBIG))
    assert (caught.value.filename, caught.value.filename2) == (str(out / "train" / "x.png"), None)
    # a file that is nobody's temporary keeps its own name
    with file_size_limit(1024), pytest.raises(OSError) as caught, naming_errors(out):
        shutil.copyfile(source, tmp_path / "elsewhere.png")
    assert caught.value.filename2 == str(tmp_path / "elsewhere.png")


def test_errors_naming_no_temporary_keep_their_names_and_a_nameless_one_gets_the_path(
    tmp_path: Path,
) -> None:
    out = tmp_path / "DS"
    descriptor = OSError(errno.EIO, "Input/output error")
    descriptor.filename = 3  # an fd, as some calls name it: not a path, kept as it is
    for error, named in (
        (OSError(errno.ENOSPC, "No space left on device"), str(out)),
        (OSError(errno.EACCES, "Permission denied", str(tmp_path / "source.png")), None),
        (descriptor, None),
    ):
        with pytest.raises(OSError) as caught, naming_errors(out):
            raise error
        assert caught.value.errno == error.errno
        assert caught.value.filename == (error.filename if named is None else named)
