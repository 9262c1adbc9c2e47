"""Atomic writes: all or nothing, with the permissions a plain open() would give."""

from __future__ import annotations

import os
import stat

import pytest

from ao4d._atomic import all_or_nothing, atomic_open, atomic_path


def test_replaces_only_on_success(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="boom"), atomic_open(target, "w") as fh:
        fh.write("half")
        raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"], "temporary file left behind"
    with atomic_open(target, "w") as fh:
        fh.write("new")
    assert target.read_text() == "new"


def test_permissions_follow_umask(tmp_path):
    mask = os.umask(0o022)
    try:
        with atomic_path(tmp_path / "a.bin") as tmp:
            tmp.write_bytes(b"x")
    finally:
        os.umask(mask)
    assert stat.S_IMODE((tmp_path / "a.bin").stat().st_mode) == 0o644


def test_keeps_suffix_for_writers_that_choose_format_by_extension(tmp_path):
    with atomic_path(tmp_path / "mesh.vtu") as tmp:
        assert tmp.suffix == ".vtu"
        tmp.write_bytes(b"")


def test_rejects_read_mode(tmp_path):
    with pytest.raises(ValueError, match="mode"), atomic_open(tmp_path / "x", "r"):
        pass


def test_never_touches_the_process_umask(tmp_path, monkeypatch):
    # os.umask is process-wide: setting it even for a moment changes other threads' new files
    def forbidden(mask):
        raise AssertionError("os.umask called")

    monkeypatch.setattr(os, "umask", forbidden)
    with atomic_open(tmp_path / "a.txt", "w") as fh:
        fh.write("x")
    assert (tmp_path / "a.txt").read_text() == "x"


def test_unwritable_folder_error_names_the_target_not_the_temporary(tmp_path, monkeypatch):
    # a read-only folder, as root sees none: every file creation there is refused
    def refuse(path, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(os, "open", refuse)
    with pytest.raises(PermissionError) as err, atomic_path(tmp_path / "page.html"):
        pass
    assert "page.html" in str(err.value) and ".tmp" not in str(err.value)


@pytest.mark.parametrize("mode", ["paths", "folder"])
def test_all_or_nothing_restores_replaced_files_and_removes_new_ones(tmp_path, mode):
    old, new, same = tmp_path / "old.txt", tmp_path / "new.txt", tmp_path / "same.txt"
    old.write_text("old content")
    old.chmod(0o640)
    same.write_text("left alone")
    scope = {"paths": [old, new, same]} if mode == "paths" else {"folder": tmp_path}
    with pytest.raises(RuntimeError, match="boom"), all_or_nothing(**scope):
        with atomic_open(old, "w") as fh:
            fh.write("new content")
        with atomic_open(new, "w") as fh:
            fh.write("a new file")
        assert old.read_text() == "new content"
        raise RuntimeError("boom")
    assert old.read_text() == "old content"
    assert stat.S_IMODE(old.stat().st_mode) == 0o640
    assert same.read_text() == "left alone"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.txt", "same.txt"], "backup or new file left"


def test_all_or_nothing_keeps_the_new_set_on_success(tmp_path):
    old = tmp_path / "old.txt"
    old.write_text("old content")
    with all_or_nothing([old]):
        with atomic_open(old, "w") as fh:
            fh.write("new content")
    assert old.read_text() == "new content"
    assert [p.name for p in tmp_path.iterdir()] == ["old.txt"]
