"""Safe file output: checked before the work, atomic, and nothing partial left behind.

Every write goes to a temporary file in the destination folder, is flushed and fsynced, then
``os.replace``d: an interrupted write leaves the old file or the new one, never half. Commands
check each output path before long work starts (:func:`check_output_file`,
:func:`check_output_folder`: right suffix, not a folder, a folder that can be written) and write
their files inside :func:`all_or_nothing`, which removes the files a run created and puts back
the ones it replaced when a later one fails.

Temporary files are created with mode ``0o666`` through ``os.open``, so the kernel applies the
process's umask as it does for a plain ``open()``: the umask is never read or changed (changing
it, even for a moment, is process-wide and would give other threads' files the wrong mode).
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Iterable

__all__ = ["atomic_path", "atomic_open", "check_output_file", "check_output_folder", "all_or_nothing"]


def _new_temp(folder: Path, prefix: str, suffix: str, target: Path) -> Path:
    """Create an empty file of a fresh name in ``folder`` with a plain ``open()``'s mode.

    An ``OSError`` names ``target`` (what the caller asked for), not the hidden temporary name.
    """
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        tmp = folder / f"{prefix}{secrets.token_hex(4)}{suffix}"
        try:
            os.close(os.open(tmp, flags, 0o666))  # the umask applies, as for open(path, "w")
        except FileExistsError:
            continue
        except OSError as exc:
            raise type(exc)(exc.errno, f"cannot write {str(target)!r}: {exc.strerror}") from None
        return tmp
    raise FileExistsError(f"cannot find a free temporary name for {str(target)!r}")  # pragma: no cover


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it replaces ``path`` atomically.

    For libraries that write by file name (``np.savez``, pyvista, trimesh). The temporary name
    keeps ``path``'s suffix (or ``suffix``) so that writers choosing a format by extension work.
    On any exception the temporary file is removed and ``path`` is untouched.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    ext = target.suffix if suffix is None else suffix
    tmp_path = _new_temp(target.parent, f".{target.name}.", f".tmp{ext}", target)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb", **kwargs) -> Iterator[IO]:
    """Open a temporary file for writing that atomically replaces ``path`` when closed cleanly."""
    if not mode.startswith("w"):
        raise ValueError(f"`mode` must be a write mode ('w', 'wb', ...), got {mode!r}")
    with atomic_path(path) as tmp, open(tmp, mode, **kwargs) as fh:
        yield fh
        fh.flush()


def _writable_folder(folder: Path, name: str, target: Path) -> None:
    """Raise a ``ValueError`` naming ``name`` unless files can be created in ``folder``."""
    existing = folder
    while not existing.exists():  # the folder will be created: its nearest existing parent decides
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"`{name}` {str(target)!r}: {str(existing)!r} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".ao4d-write-test.", dir=existing)
    except OSError as exc:
        raise ValueError(f"`{name}` {str(target)!r}: cannot write in {str(existing)!r} ({exc.strerror})") from None
    os.close(fd)
    os.unlink(probe)


def check_output_file(path: str | os.PathLike, name: str, suffixes: Iterable[str] | None = None) -> Path:
    """``path`` as a Path if a file can be written there, else a ``ValueError`` naming ``name``.

    Checked before any work: the suffix is one of ``suffixes`` (case-insensitive), the path is not
    an existing folder, and its folder (or the nearest existing parent) accepts new files.
    """
    target = Path(path)
    if target.is_dir():
        raise ValueError(f"`{name}` {str(target)!r} is a folder; give a file name")
    if suffixes is not None:
        allowed = tuple(s.lower() for s in suffixes)
        if not target.name.lower().endswith(allowed):
            raise ValueError(f"`{name}` must end in {' or '.join(allowed)}, got {str(target)!r}")
    _writable_folder(target.parent, name, target)
    return target


def check_output_folder(path: str | os.PathLike, name: str) -> Path:
    """``path`` as a Path if it is (or can become) a writable folder, else a ``ValueError``."""
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise ValueError(f"`{name}` {str(target)!r} is a file; give a folder")
    _writable_folder(target, name, target)
    return target


@contextlib.contextmanager
def all_or_nothing(
    paths: Iterable[str | os.PathLike] = (), *, folder: str | os.PathLike | None = None
) -> Iterator[None]:
    """Undo this block's file changes among ``paths`` (or anywhere in ``folder``) if it fails.

    Before the block, every file that exists among ``paths`` (or in ``folder``) gets a hidden
    hard link beside it (a copy where the filesystem has no hard links): writers replace files
    atomically (:func:`atomic_path`), so the link keeps the old content. On an exception the
    files the block created are removed and the ones it replaced are put back, so the set is as
    it was; on success the links are dropped.
    """
    targets = [Path(p) for p in paths]
    where = None if folder is None else Path(folder)
    if where is not None and where.is_dir():
        targets += [p for p in where.iterdir() if p.is_file() and not p.name.startswith(".ao4d-keep.")]
    kept: dict[Path, Path] = {}
    try:
        for p in dict.fromkeys(targets):
            if p.is_file():
                kept[p] = _keep(p)
    except BaseException:
        for backup in kept.values():
            backup.unlink()
        raise
    listed = set(where.iterdir()) if where is not None and where.is_dir() else set()
    try:
        yield
    except BaseException:
        new = [p for p in targets if p not in kept]
        if where is not None and where.is_dir():
            new += [p for p in where.iterdir() if p not in listed and p.is_file()]
        for p in new:
            with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                p.unlink()
        for p, backup in kept.items():
            if p.exists() and os.path.samefile(p, backup):  # untouched: rename would do nothing
                backup.unlink()
            else:
                os.replace(backup, p)
        raise
    else:
        for backup in kept.values():
            with contextlib.suppress(FileNotFoundError):
                backup.unlink()


def _keep(path: Path) -> Path:
    """A hidden second name for ``path``'s current content, in its folder (hard link or copy)."""
    for _ in range(100):
        backup = path.parent / f".ao4d-keep.{secrets.token_hex(4)}.{path.name}"
        try:
            os.link(path, backup)
            return backup
        except FileExistsError:
            continue
        except OSError:  # no hard links here (some network and FAT filesystems): copy
            break
    backup = _new_temp(path.parent, ".ao4d-keep.", f".{path.name}", path)
    shutil.copy2(path, backup)
    return backup
