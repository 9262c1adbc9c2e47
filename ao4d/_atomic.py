"""Safe file output: checked before the work, atomic, and nothing partial left behind.

Every write goes to a temporary file in the destination folder, is flushed and fsynced, then
``os.replace``d: an interrupted write leaves the old file or the new one, never half. Commands
check each output path before long work starts (:func:`check_output_file`,
:func:`check_output_folder`: right suffix, not a folder, a folder that can be written) and write
their files inside :func:`all_or_nothing`, which removes the files a run created when a later
one fails.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Iterable

__all__ = ["atomic_path", "atomic_open", "check_output_file", "check_output_folder", "all_or_nothing"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


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
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{ext}", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp creates 0600; give the file the permissions a plain open() would
        os.chmod(tmp_path, 0o666 & ~_umask())
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
def all_or_nothing(paths: Iterable[str | os.PathLike] = (), *, folder: str | os.PathLike | None = None
                   ) -> Iterator[None]:
    """Remove the files this block created among ``paths`` (or anywhere in ``folder``) if it fails.

    Files that existed before are replaced atomically by their writers, so after a failure each
    path holds its old content or the complete new one, and no new file is left half a set.
    """
    targets = [Path(p) for p in paths]
    where = None if folder is None else Path(folder)
    before = {p for p in targets if p.exists()}
    listed = set(where.iterdir()) if where is not None and where.is_dir() else set()
    try:
        yield
    except BaseException:
        new = [p for p in targets if p not in before]
        if where is not None and where.is_dir():
            new += [p for p in where.iterdir() if p not in listed and p.is_file()]
        for p in new:
            with contextlib.suppress(FileNotFoundError, IsADirectoryError):
                p.unlink()
        raise
