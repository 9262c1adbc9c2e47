"""Where a run's files live: a local folder, or any fsspec URL (``s3://``, ``gs://``, ``file://``).

A :class:`Store` reads and writes files by relative POSIX paths under its root, every write
atomic (the whole file or nothing): a local folder through ``ao4d._atomic``, an fsspec
filesystem by writing a hidden temporary file beside the target and moving it into place (a
rename on a local or network filesystem; on object stores each object appears whole). So the
runner's protocol — each file atomic, an item's ``record.json`` last — is the same everywhere,
and any process that can reach the URL can write its own items.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import stat
import uuid
from pathlib import Path
from typing import Any

from ao4d._atomic import atomic_open

__all__ = ["Store", "LocalStore", "FsspecStore", "MemoryStore", "open_store", "is_url", "check_url"]

_BLOCK = 1 << 20


# an URL's protocol: a scheme (RFC 3986), or fsspec's chain of them ("simplecache::s3")
_PROTOCOL = re.compile(r"[A-Za-z][A-Za-z0-9+.\-]*(::[A-Za-z][A-Za-z0-9+.\-]*)*")


def is_url(out: Any) -> bool:
    """True when ``out`` is a string with a protocol (``proto://...``), not a local path."""
    return isinstance(out, str) and "://" in out


def check_url(out: str, name: str = "out") -> str:
    """Refuse a malformed URL ``out`` (``"://x"`` would otherwise be read as the local folder
    ``./:/x``): the part before ``://`` must be a protocol and the part after it a path.

    Raises
    ------
    ValueError
        Naming ``out`` and the form expected.
    """
    protocol, _, path = out.partition("://")
    if not _PROTOCOL.fullmatch(protocol) or not path.strip("/"):
        raise ValueError(
            f"`{name}` {out!r} is not a URL of the form PROTOCOL://PATH (such as "
            "s3://bucket/run or file:///data/run) nor a local folder; give a folder "
            "path without '://' or a complete URL"
        )
    return out


def open_store(out: str | os.PathLike, name: str = "out") -> Store:
    """The store of ``out``: :class:`FsspecStore` for a URL, else :class:`LocalStore`.

    ``name`` is the parameter that errors name (``out`` for the writer, ``path`` for
    the loader).

    Raises
    ------
    ValueError
        A malformed URL (:func:`check_url`), or one whose protocol fsspec does not know or
        whose filesystem package is missing (``s3fs`` for ``s3://``, ``gcsfs`` for
        ``gs://``), naming ``name``.
    """
    if isinstance(out, str) and not out.strip():
        raise ValueError(f"`{name}` is empty; give a folder path or a URL")
    if is_url(out):
        return FsspecStore(check_url(out, name), name)
    return LocalStore(Path(out))


def _naming(exc: OSError, path: str) -> OSError:
    """``exc`` with ``path`` as its file name when it names none (a write cut short by a full
    disk names no file), so that messages say which file could not be written."""
    if exc.filename is not None or exc.errno is None:
        return exc
    return type(exc)(exc.errno, exc.strerror or str(exc), str(path))


class Store:
    """Files by relative POSIX path (``"items/00003/record.json"``) under one root."""

    #: how the root is shown in messages and in the run summary
    name: str
    #: True when the files live in this process only (fsspec's ``memory://``): other
    #: processes cannot see them and they are gone when this process exits
    process_local: bool = False

    def read_bytes(self, rel: str) -> bytes:
        raise NotImplementedError

    def read_text(self, rel: str) -> str:
        return self.read_bytes(rel).decode("utf-8")

    def write_bytes(self, rel: str, data: bytes) -> None:
        """Write ``data`` to ``rel`` atomically, creating its folders; a failed write (a full
        disk) leaves the old file, or none, and no temporary file."""
        raise NotImplementedError

    def create_bytes(self, rel: str, data: bytes) -> bool:
        """Write ``data`` to ``rel`` atomically unless ``rel`` exists; return whether it wrote.

        Exclusive on a local folder (of two processes creating the same file, exactly one
        does); on other filesystems a check, then a write.
        """
        if self.is_file(rel):
            return False
        self.write_bytes(rel, data)
        return True

    def is_file(self, rel: str) -> bool:
        raise NotImplementedError

    def files(self, rel: str = "") -> list[str]:
        """Names of the files directly in folder ``rel``, sorted (empty if it does not exist)."""
        raise NotImplementedError

    def size(self, rel: str) -> int:
        raise NotImplementedError

    def remove(self, rel: str) -> None:
        """Delete file ``rel`` if it exists."""
        raise NotImplementedError

    def sha256(self, rel: str) -> str:
        """Hex SHA-256 of file ``rel``'s bytes."""
        raise NotImplementedError

    def prepare(self) -> bool:
        """Create the root if needed; return whether it holds anything. Errors name ``out``."""
        raise NotImplementedError


class LocalStore(Store):
    """A folder on this machine (writes through :func:`ao4d._atomic.atomic_open`)."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.name = str(root)

    def _path(self, rel: str) -> Path:
        return self.root / rel if rel else self.root

    def read_bytes(self, rel: str) -> bytes:
        path = self._path(rel)
        # a FIFO or a device would block or never end: only regular files are read
        if not stat.S_ISREG(path.stat().st_mode):
            raise OSError(errno.EINVAL, "not a regular file (a folder, FIFO or device)", str(path))
        return path.read_bytes()

    def write_bytes(self, rel: str, data: bytes) -> None:
        path = self._path(rel)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_open(path, "wb") as fh:
                fh.write(data)
        except OSError as exc:
            raise _naming(exc, str(path)) from None

    def create_bytes(self, rel: str, data: bytes) -> bool:
        path = self._path(rel)
        path.parent.mkdir(parents=True, exist_ok=True)
        temp = path.parent / f".{path.name}.{uuid.uuid4().hex[:12]}.tmp"
        try:
            with atomic_open(temp, "wb") as fh:
                fh.write(data)
            try:
                os.link(temp, path)  # fails when ``path`` exists: exclusive, and whole
            except FileExistsError:
                return False
            except OSError:  # no hard links here (some network and FAT filesystems)
                return super().create_bytes(rel, data)
            return True
        finally:
            temp.unlink(missing_ok=True)

    def is_file(self, rel: str) -> bool:
        return self._path(rel).is_file()

    def files(self, rel: str = "") -> list[str]:
        folder = self._path(rel)
        if not folder.is_dir():
            return []
        return sorted(p.name for p in folder.iterdir() if p.is_file())

    def size(self, rel: str) -> int:
        return self._path(rel).stat().st_size

    def remove(self, rel: str) -> None:
        self._path(rel).unlink(missing_ok=True)

    def sha256(self, rel: str) -> str:
        digest = hashlib.sha256()
        with open(self._path(rel), "rb") as fh:
            for block in iter(lambda: fh.read(_BLOCK), b""):
                digest.update(block)
        return digest.hexdigest()

    def prepare(self) -> bool:
        out = self.root
        if out.exists() and not out.is_dir():
            raise ValueError(
                f"`out` {self.name!r} is a file; it must be a folder (new, empty, or of an earlier run of this config)"
            )
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"cannot create the output folder `out` {self.name!r}: {exc.strerror or exc}") from None
        return any(out.iterdir())


class MemoryStore(Store):
    """Files held in this object: where a dask worker that cannot see the output makes an
    item, whose files it then sends back (:func:`datasets_gen.items.write_item`)."""

    def __init__(self) -> None:
        self.name = "memory (scratch)"
        self.process_local = True
        self._files: dict[str, bytes] = {}

    def read_bytes(self, rel: str) -> bytes:
        try:
            return self._files[rel]
        except KeyError:
            raise FileNotFoundError(rel) from None

    def write_bytes(self, rel: str, data: bytes) -> None:
        self._files[rel] = bytes(data)

    def is_file(self, rel: str) -> bool:
        return rel in self._files

    def files(self, rel: str = "") -> list[str]:
        prefix = f"{rel}/" if rel else ""
        return sorted(k[len(prefix) :] for k in self._files if k.startswith(prefix) and "/" not in k[len(prefix) :])

    def size(self, rel: str) -> int:
        return len(self.read_bytes(rel))

    def remove(self, rel: str) -> None:
        self._files.pop(rel, None)

    def sha256(self, rel: str) -> str:
        return hashlib.sha256(self.read_bytes(rel)).hexdigest()

    def prepare(self) -> bool:
        return bool(self._files)


class FsspecStore(Store):
    """A folder behind an fsspec URL; each write goes to a hidden temporary name first and is
    then moved into place, so a reader never sees part of a file."""

    def __init__(self, url: str, name: str = "out"):
        import fsspec

        self.name = url
        try:
            self.fs, self.root = fsspec.core.url_to_fs(url)
        except (ImportError, ValueError) as exc:  # unknown protocol, or its package missing
            raise ValueError(f"cannot open `{name}` {url!r}: {exc}") from None
        self.root = self.root.rstrip("/")
        try:
            from fsspec.implementations.memory import MemoryFileSystem

            self.process_local = isinstance(self.fs, MemoryFileSystem)
        except ImportError:  # pragma: no cover - fsspec without its memory filesystem
            pass

    def _path(self, rel: str) -> str:
        return f"{self.root}/{rel}" if rel else self.root

    def read_bytes(self, rel: str) -> bytes:
        return self.fs.cat_file(self._path(rel))

    def write_bytes(self, rel: str, data: bytes) -> None:
        path = self._path(rel)
        parent, _, base = path.rpartition("/")
        self.fs.makedirs(parent, exist_ok=True)
        temp = f"{parent}/.{base}.{uuid.uuid4().hex[:12]}.tmp"
        try:
            self.fs.pipe_file(temp, data)
            self.fs.mv(temp, path)
        except BaseException as exc:
            # a write cut short (a full disk) may have left part of the temporary file
            with contextlib.suppress(OSError):
                if self.fs.exists(temp):
                    self.fs.rm_file(temp)
            if isinstance(exc, OSError):
                raise _naming(exc, f"{self.name.rstrip('/')}/{rel}") from None
            raise

    def is_file(self, rel: str) -> bool:
        return self.fs.isfile(self._path(rel))

    def files(self, rel: str = "") -> list[str]:
        path = self._path(rel)
        try:
            entries = self.fs.ls(path, detail=True)
        except FileNotFoundError:
            return []
        return sorted(e["name"].rstrip("/").rpartition("/")[2] for e in entries if e["type"] == "file")

    def size(self, rel: str) -> int:
        return int(self.fs.size(self._path(rel)))

    def remove(self, rel: str) -> None:
        path = self._path(rel)
        if self.fs.isfile(path):
            self.fs.rm_file(path)

    def sha256(self, rel: str) -> str:
        digest = hashlib.sha256()
        with self.fs.open(self._path(rel), "rb") as fh:
            for block in iter(lambda: fh.read(_BLOCK), b""):
                digest.update(block)
        return digest.hexdigest()

    def prepare(self) -> bool:
        try:
            if self.fs.isfile(self.root):
                raise ValueError(
                    f"`out` {self.name!r} is a file; it must be a folder (new, "
                    "empty, or of an earlier run of this config)"
                )
            self.fs.makedirs(self.root, exist_ok=True)
            return bool(self.fs.ls(self.root))
        except OSError as exc:
            raise ValueError(f"cannot create the output folder `out` {self.name!r}: {exc.strerror or exc}") from None
