"""Read 2D/3D/4D grids of values from data files: one reader for the Python API and the CLI.

:func:`read_grid` takes a path and returns a :class:`Grid`: the values (a memory map or a
lazy dask array: nothing large is read up front), the grid spacing and origin (from the file
where it has them, else 1 and 0; ``spacing=``/``origin=`` override) and where they came from.
Then ``ao4d.extract(grid.values, level, spacing=grid.spacing, origin=grid.origin)``.

Formats (chosen by the name):

============================  =================================================================
``x.npy``                     memory-mapped (``np.load(mmap_mode="r")``); no spacing/origin
``x.nii``, ``x.nii.gz``       NIfTI-1/2 (nibabel). Spacing and origin from the affine when it is
                              axis-aligned (a negative step flips that axis so that the mesh is
                              in scanner coordinates), else a warning and the voxel axes with the
                              header's zooms. The 4th axis: ``pixdim[4]`` and ``toffset``.
                              ``.nii`` is memory-mapped (lazy when scaled); ``.nii.gz`` is
                              decompressed once into memory (gzip cannot be sliced cheaply).
``x.zarr[:/path]``            zarr array (lazy dask); attributes ``spacing``/``origin`` if set
``x.h5:/path/to/dataset``     HDF5 dataset (h5py, lazy dask; also ``.hdf5``, ``.hdf``);
                              attributes ``spacing``/``origin`` if set
``x.mhd``, ``x.mha``          MetaImage of any dimension (header parsed here, since VTK reads
                              3D only), raw data memory-mapped; ``ElementSpacing``, ``Offset``
``frames_*.vti`` (a glob)     3D frames stacked along w in natural sort order (``f2`` before
                              ``f10``), lazily, one frame per block: ``.vti``, ``.mhd``,
                              ``.npy``, ``.nii``/``.nii.gz``; x, y, z spacing and origin from the
                              first frame, w from ``spacing``/``origin`` (default 1, 0)
============================  =================================================================

Lazy arrays read through small picklable sources that open the file by name, so the same
grid runs on a ``distributed`` cluster when its workers see the same path (a shared
filesystem or object store); ``chunks=`` turns any format into a dask array.

Bad files raise before any long work, naming the file: ``FileNotFoundError`` when it (or every
match of a glob) is missing; ``ValueError`` when it is truncated, not of its format, a dataset
path does not exist, frames have different shapes, or it has the wrong dimension for ``ndim``.

Why this file is long: the formats stay one module because they share the dispatch, the lazy
file-backed sources, the error wording and the frame stacking (a frame is any of the formats).
(:mod:`ao4d.volumes` writes and reads ao4d's own 3D output volumes; this module reads input
data of any origin.)
"""

from __future__ import annotations

import glob as globmod
import math
import os
import re
import warnings
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._dask import block_sizes, is_dask_array
from ._npz import npy_problem
from ._optional import require
from ._validate import as_real, as_vector, check_bool, check_grid_lengths, check_memory, regular_file

__all__ = ["Grid", "read_grid", "ObliqueAffineWarning", "natural_key", "FRAME_SUFFIXES"]

FRAME_SUFFIXES = (".vti", ".mhd", ".mha", ".npy", ".nii", ".nii.gz")
_H5_SUFFIXES = (".h5", ".hdf5", ".hdf", ".he5")


class ObliqueAffineWarning(UserWarning):
    """A NIfTI or MetaImage orientation is not axis-aligned: the voxel axes are used instead."""


@dataclass(frozen=True)
class Grid:
    """A grid of values read from a file.

    Attributes
    ----------
    values : (n_0, ..., n_{d-1}) ndarray, np.memmap or dask array
        ``values[i]`` sits at ``origin + spacing * i`` (axis k is coordinate k).
    spacing : (d,) float64 ndarray
    origin : (d,) float64 ndarray
    source : str
        The path (or glob) read.
    notes : tuple of str
        Where spacing and origin came from, and what the reader did (flips, overrides).
    units : tuple of str
        The file's unit per axis (NIfTI ``xyzt_units``: ``"mm"``, ``"ms"``, ...; ``"unknown"``),
        empty where the format has none. A w axis in a time unit is scaled to a length (see
        ``w_scale``).
    w_scale : float or None
        Length units per time unit used for a NIfTI time axis (w step = ``pixdim[4] * w_scale``),
        or None where no time axis was scaled.
    affine : (d + 1, d + 1) float64 ndarray or None
        With ``read_grid(..., keep_affine=True)``: grid index to coordinates (the file's affine, e.g.
        oblique scanner axes); pass it to ``ao4d.extract(values, level, affine=grid.affine)``.
        None otherwise (``spacing`` and ``origin`` place the grid).
    """

    values: Any
    spacing: np.ndarray
    origin: np.ndarray
    source: str
    notes: tuple[str, ...] = field(default=())
    units: tuple[str, ...] = field(default=())
    w_scale: float | None = None
    affine: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(int(n) for n in self.values.shape)

    @property
    def ndim(self) -> int:
        return len(self.values.shape)

    @property
    def lazy(self) -> bool:
        """True when the values are a dask array (read block by block when used)."""
        return is_dask_array(self.values)

    def __repr__(self) -> str:
        kind = "dask" if self.lazy else type(self.values).__name__
        return (
            f"Grid({self.source!r}, shape={self.shape}, dtype={self.values.dtype}, {kind}, "
            f"spacing={self.spacing.tolist()}, origin={self.origin.tolist()})"
        )


def natural_key(text: str) -> list:
    """Sort key that orders digit runs by value: ``f2`` before ``f10``.

    Parameters
    ----------
    text : str
        A file name.

    Returns
    -------
    list of str and int
        The key: text in lower case, digit runs as numbers.
    """
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", text)]


# --------------------------------------------------------------------------------------------
# public entry point
# --------------------------------------------------------------------------------------------


def read_grid(
    path: str | os.PathLike,
    *,
    spacing: Any = None,
    origin: Any = None,
    ndim: int | tuple[int, ...] | None = None,
    chunks: Any = None,
    w_scale: float | None = None,
    keep_affine: bool = False,
) -> Grid:
    """Open a 2D/3D/4D grid of values from a file, lazily.

    Parameters
    ----------
    path : str or path-like
        A ``.npy``, ``.nii``/``.nii.gz``, ``.zarr`` (optionally ``store.zarr:/array/path``),
        ``file.h5:/path/to/dataset``, ``.mhd``/``.mha`` file, or a glob of 3D frames
        (``"frames_*.vti"``, ``*.mhd``, ``*.npy``, ``*.nii.gz``) stacked along w.
    spacing : float or (d,) sequence, optional
        Overrides the file's grid step (> 0); a ``None`` entry keeps the file's step on that
        axis (``spacing=(None, None, None, 0.5)`` sets only w).
    origin : float or (d,) array_like, optional
        Overrides the file's first grid point.
    ndim : int or tuple of int, optional
        Dimensions accepted (default 2, 3 or 4); e.g. ``ndim=4`` refuses a 3D file.
    chunks : int, tuple or "auto", optional
        Return the values as a dask array in these chunks (points per block) even for formats
        read as memory maps, e.g. to extract on a ``distributed`` cluster.
    w_scale : float, optional
        Length units per time unit for the w axis of a 4D NIfTI whose ``xyzt_units`` give it a
        time (``pixdim[4] = 2000`` ms with ``w_scale=0.001`` gives a w step of 2). Without it a
        time axis is not taken as a length: one frame is one mean x/y/z step (noted in
        ``notes``). A w step in ``spacing`` wins over both.
    keep_affine : bool
        Keep the file's full index-to-coordinates affine in :attr:`Grid.affine` (NIfTI: oblique
        scanner axes and negative steps as they are, no flips, no warning) for
        ``ao4d.extract(..., affine=grid.affine)``; formats without one get the diagonal affine
        of their spacing and origin.

    Returns
    -------
    Grid
        ``values`` (memory map or dask array), ``spacing``, ``origin``, ``source``, ``notes``.

    Raises
    ------
    FileNotFoundError
        The file, a dataset's file, or every match of a glob is missing.
    ValueError
        Unknown format, truncated or malformed file, missing dataset path, frames of different
        shapes or kinds, or a dimension outside ``ndim``.

    Examples
    --------
    >>> import numpy as np, os, shutil, tempfile
    >>> folder = tempfile.mkdtemp()
    >>> for k in range(3):
    ...     np.save(os.path.join(folder, f"frame_{k}.npy"), np.full((4, 5, 6), float(k)))
    >>> grid = read_grid(os.path.join(folder, "frame_*.npy"), spacing=0.5)
    >>> grid.shape, grid.spacing.tolist(), float(grid.values[0, 0, 0, 2].compute())
    ((4, 5, 6, 3), [0.5, 0.5, 0.5, 0.5], 2.0)
    >>> shutil.rmtree(folder)
    """
    text = os.fspath(path)
    if not isinstance(text, str) or not text:
        raise TypeError(f"`path` must be a non-empty file name, got {path!r}")
    if ndim is not None and not (_is_int(ndim) or (isinstance(ndim, tuple) and ndim and all(_is_int(k) for k in ndim))):
        raise TypeError(f"`ndim` must be an int or a tuple of ints (2, 3, 4), got {ndim!r}")
    if w_scale is not None:
        w_scale = as_real(w_scale, "w_scale", gt=0)
    keep_affine = check_bool(keep_affine, "keep_affine")
    if text.endswith(("/", os.sep)) and text.rstrip("/" + os.sep).lower().endswith(".zarr"):
        text = text.rstrip("/" + os.sep)
    inner = _split_inner(text, _H5_SUFFIXES + (".zarr",))
    pattern = text if inner is None else inner[0]
    scale = {"w_scale": w_scale, "affine": keep_affine, "w_step": _w_override(spacing)}
    if any(ch in pattern for ch in "*?[") and not Path(pattern).exists():
        values, step, start, notes = _read_frames(text)
    else:
        values, step, start, notes = _read_one(text, scale)
    d = len(values.shape)
    allowed = (2, 3, 4) if ndim is None else ((ndim,) if isinstance(ndim, int) else tuple(ndim))
    if d not in allowed:
        if ndim is None:  # the words of ao4d.extract, with the file named
            raise ValueError(f"`values` must be a 2D, 3D or 4D array, got shape {tuple(values.shape)} from {text!r}")
        words = ", ".join(f"{k}D" for k in allowed[:-1])
        words = f"{words} or {allowed[-1]}D" if words else f"{allowed[-1]}D"
        raise ValueError(f"{text!r} holds a {d}D grid of shape {tuple(values.shape)}; a {words} grid is needed")
    if any(n < 2 for n in values.shape):
        raise ValueError(f"{text!r} has shape {tuple(values.shape)}: every axis needs >= 2 points")
    notes = list(notes)
    if w_scale is not None and scale.get("w_scaled") is None:
        raise ValueError(
            f"`w_scale` scales a time axis, and {text!r} has none (a 4D NIfTI with "
            "time units in xyzt_units); use `spacing` instead"
        )
    if spacing is not None:
        step = _merge_spacing(spacing, step, d)
        notes.append("spacing given")
    if origin is not None:
        start = as_vector(origin, "origin", d)
        notes.append("origin given")
    if chunks is not None:
        values = _as_dask(values, chunks, text)
    step, start = np.asarray(step, np.float64), np.asarray(start, np.float64)
    extent = np.abs(start) + np.abs(step) * (np.asarray(values.shape, dtype=np.float64) + 1.0)
    if w_scale is not None and spacing is None:
        check_grid_lengths(step, extent, "w_scale", hint=f" (the grid steps of {text!r}: {step.tolist()})")
    else:
        check_grid_lengths(
            step, extent, "spacing", hint=f" (the grid steps of {text!r}: {step.tolist()}; `spacing=` overrides them)"
        )
    matrix = None
    if keep_affine:
        matrix = scale.get("affine_matrix")
        if matrix is None:
            matrix = np.eye(d + 1)
            matrix[:d, :d] = np.diag(step)
            matrix[:d, d] = start
        else:  # the file's affine, with the given steps and origin in place of its own
            matrix = np.array(matrix, dtype=np.float64)
            given = np.flatnonzero(_given_axes(spacing, d))
            if given.size:  # each given axis keeps its direction (oblique rotation included)
                length = np.linalg.norm(matrix[:d, given], axis=0)
                matrix[:d, given] *= step[given] / length
                notes.append(
                    f"the affine's axes {', '.join('xyzw'[k] for k in given)} "
                    "take the given spacing (their directions kept)"
                )
            if origin is not None:
                matrix[:d, d] = start
                notes.append("the affine's translation is the given origin")
    return Grid(values, step, start, text, tuple(notes), tuple(scale.get("units", ())), scale.get("w_scaled"), matrix)


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def _w_override(spacing: Any) -> float | None:
    """The w step ``spacing`` sets (a 4-entry sequence with a number last), else None."""
    if isinstance(spacing, (list, tuple, np.ndarray)) and len(spacing) == 4 and spacing[3] is not None:
        return as_real(spacing[3], "spacing", gt=0)  # its w entry: named like the rest
    return None


def _given_axes(spacing: Any, d: int) -> np.ndarray:
    """(d,) bool: the axes whose step ``spacing`` sets (None: none; a None entry keeps the file's)."""
    if spacing is None:
        return np.zeros(d, dtype=bool)
    if isinstance(spacing, (list, tuple)) and len(spacing) == d:
        return np.array([s is not None for s in spacing])
    return np.ones(d, dtype=bool)


def _merge_spacing(spacing: Any, step: np.ndarray, d: int) -> np.ndarray:
    """``spacing`` over the file's ``step``: a scalar, or per axis with None keeping the file's."""
    if isinstance(spacing, (list, tuple)) and any(s is None for s in spacing):
        if len(spacing) != d:
            raise ValueError(f"`spacing` must be a scalar or have {d} entries, got {len(spacing)}")
        given = [k for k, s in enumerate(spacing) if s is not None]
        out = np.array(step, dtype=np.float64)
        if given:
            out[given] = as_vector([spacing[k] for k in given], "spacing", len(given), positive=True)
        return out
    return as_vector(spacing, "spacing", d, positive=True)


# --------------------------------------------------------------------------------------------
# dispatch
# --------------------------------------------------------------------------------------------


def _suffix(name: str) -> str:
    lower = name.lower()
    return ".nii.gz" if lower.endswith(".nii.gz") else Path(lower).suffix


def _split_inner(text: str, suffixes: tuple[str, ...]) -> tuple[str, str] | None:
    """``file.h5:/a/b`` -> (``file.h5``, ``/a/b``) for a file with one of ``suffixes``."""
    pattern = "|".join(re.escape(s) for s in suffixes)
    match = re.match(rf"^(.*?(?:{pattern}))(?::(.*))?$", text, flags=re.IGNORECASE)
    if match is None:
        return None
    return match.group(1), (match.group(2) or "")


def _missing(path: str, what: str = "file") -> FileNotFoundError:
    return FileNotFoundError(f"{what} {path!r} does not exist")


def _read_one(text: str, scale: dict | None = None) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    h5 = _split_inner(text, _H5_SUFFIXES)
    if h5 is not None:
        return _read_hdf5(*h5)
    zarr_parts = _split_inner(text, (".zarr",))
    if zarr_parts is not None:
        return _read_zarr(*zarr_parts)
    if not Path(text).exists():
        raise _missing(text)
    regular_file(text, "path")  # a FIFO would block the reader, a folder fail obscurely
    suffix = _suffix(text)
    if suffix == ".npy":
        values = _open_npy(text)
        d = values.ndim
        return values, np.ones(d), np.zeros(d), ["no spacing/origin in .npy: 1, 0"]
    if suffix in (".nii", ".nii.gz"):
        return _read_nifti(text, scale=scale)
    if suffix in (".mhd", ".mha"):
        return _read_metaimage(text)
    if suffix == ".vti":
        return _read_vti(text)
    raise ValueError(
        f"{text!r}: unknown format {suffix or '(no suffix)'!r}; expected .npy, .nii, "
        ".nii.gz, .zarr, .h5:/dataset, .mhd, .mha, or a glob of 3D frames"
    )


def _as_dask(values: Any, chunks: Any, text: str) -> Any:
    da = require("dask.array", "`chunks` (blocks as dask tasks)")
    import dask.base

    sizes = block_sizes(chunks, tuple(int(n) for n in values.shape))
    if is_dask_array(values):
        return values.rechunk(sizes)
    if isinstance(values, np.memmap) and values.filename:
        # a file-backed source pickles as its name (a memmap would pickle its whole contents)
        return da.from_array(
            _view_source(values),
            chunks=sizes,
            asarray=True,
            fancy=False,
            name=f"file-{dask.base.tokenize(_view_source(values), os.path.getmtime(values.filename))}",
        )
    return da.from_array(np.asarray(values), chunks=sizes)


def _view_source(values: np.memmap) -> _ViewSource:
    """The file-backed description of a memory map or of any view of one (reshaped, flipped):
    its first element's byte position in the file and its strides."""
    root = values
    while isinstance(root.base, np.memmap):
        root = root.base
    # a view's `offset` is its root's; the data pointers give the view's own start
    start = int(root.offset) + (values.__array_interface__["data"][0] - root.__array_interface__["data"][0])
    return _ViewSource(
        str(values.filename),
        tuple(int(n) for n in values.shape),
        values.dtype.str,
        start,
        tuple(int(s) for s in values.strides),
    )


# --------------------------------------------------------------------------------------------
# picklable file-backed sources (read by name on whichever process runs the task)
# --------------------------------------------------------------------------------------------


class _ArraySource:
    """What dask reads of a lazy source besides ``__getitem__``: ``ndim`` and ``dtype``, from the
    subclass's ``shape`` and ``dtype_str`` fields."""

    shape: tuple[int, ...]
    dtype_str: str

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(self.dtype_str)


@dataclass(frozen=True)
class _ViewSource(_ArraySource):
    """A strided view into a raw file (a memory map or a view of one: NIfTI reshaped to
    Fortran order, flipped axes), memory-mapped on first use in each process."""

    path: str
    shape: tuple[int, ...]
    dtype_str: str
    start: int  # byte position of element (0, ..., 0) in the file
    strides: tuple[int, ...]  # bytes, any sign

    def __getitem__(self, index: Any) -> np.ndarray:
        first = self.start + sum(s * (n - 1) for s, n in zip(self.strides, self.shape) if s < 0)
        last = self.start + sum(s * (n - 1) for s, n in zip(self.strides, self.shape) if s > 0)
        mm = np.memmap(self.path, dtype=np.uint8, mode="r", offset=first, shape=(last + self.dtype.itemsize - first,))
        view = np.ndarray(self.shape, self.dtype, buffer=mm, offset=self.start - first, strides=self.strides)
        return np.array(view[index])


@dataclass(frozen=True)
class _NiftiSource(_ArraySource):
    """A NIfTI image read (with its scaling) through nibabel's array proxy."""

    path: str
    shape: tuple[int, ...]
    dtype_str: str

    def __getitem__(self, index: Any) -> np.ndarray:
        import nibabel as nib

        try:
            values = np.asarray(nib.load(self.path).dataobj[index], dtype=self.dtype)
        except (OSError, EOFError, ValueError, zlib.error) as exc:
            raise ValueError(f"{self.path!r}: cannot read its data ({exc}); truncated?") from None
        # a 3D image stored with a time axis of one: drop it (see _nifti_open)
        return values.reshape(values.shape[: len(self.shape)]) if values.ndim > len(self.shape) else values


@dataclass(frozen=True)
class _H5Source(_ArraySource):
    """An HDF5 dataset, opened by name (h5py objects do not pickle)."""

    path: str
    dataset: str
    shape: tuple[int, ...]
    dtype_str: str

    def __getitem__(self, index: Any) -> np.ndarray:
        import h5py

        try:
            with h5py.File(self.path, "r") as fh:
                return np.asarray(fh[self.dataset][index])
        except OSError as exc:
            raise ValueError(f"{self.path!r}:{self.dataset}: cannot read its data ({exc}); truncated?") from None


def _read_frame(path: str, kind: str, shape: tuple[int, ...], dtype: str) -> np.ndarray:
    """One 3D frame as a C-ordered array (runs inside a dask task)."""
    if kind == ".vti":
        values = _vti_values(path)
    elif kind in (".mhd", ".mha"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ObliqueAffineWarning)
            values = np.asarray(_read_metaimage(path)[0])
    elif kind == ".npy":
        values = np.asarray(_open_npy(path))
    else:
        values = np.asarray(_read_nifti(path, warn=False, lazy=False)[0])
    if values.shape != shape:
        raise ValueError(f"frame {path!r} has shape {values.shape}, expected {shape} (it changed?)")
    return np.ascontiguousarray(values, dtype=np.dtype(dtype))


# --------------------------------------------------------------------------------------------
# formats
# --------------------------------------------------------------------------------------------


def _open_npy(path: str) -> np.ndarray:
    regular_file(path, "path")  # frames of a glob too: a FIFO among them would block
    try:
        values = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        size = os.path.getsize(path)
        raise ValueError(f"{path!r} is not a valid .npy file ({size} bytes; {npy_problem(path, exc)})") from None
    if not isinstance(values, np.ndarray):
        raise ValueError(f"{path!r} holds no single array")
    return values


def _attrs_grid(attrs: Any, d: int, where: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Spacing/origin from ``spacing``/``origin`` attributes (zarr, HDF5), else 1 and 0."""
    notes = []
    step, start = np.ones(d), np.zeros(d)
    if "spacing" in attrs:
        step = as_vector(np.asarray(attrs["spacing"]), f"{where} attribute `spacing`", d, positive=True)
        notes.append("spacing from the `spacing` attribute")
    if "origin" in attrs:
        start = as_vector(np.asarray(attrs["origin"]), f"{where} attribute `origin`", d)
        notes.append("origin from the `origin` attribute")
    return step, start, notes


def _read_hdf5(file: str, dataset: str) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    h5py = require("h5py", "reading HDF5")
    da = require("dask.array", "reading HDF5", extra="io")

    if not Path(file).exists():
        raise _missing(file, "HDF5 file")
    regular_file(file, "path", what="HDF5 file")
    try:
        fh = h5py.File(file, "r")
    except OSError as exc:
        raise ValueError(f"{file!r} is not a readable HDF5 file (truncated?): {exc}") from None
    with fh:
        names: list[str] = []
        fh.visititems(lambda name, obj: names.append("/" + name) if isinstance(obj, h5py.Dataset) else None)
        if not dataset:
            if len(names) != 1:
                raise ValueError(
                    f"{file!r} holds {len(names)} datasets ({', '.join(names[:8])}); "
                    f"name one as {file}:/path/to/dataset"
                )
            dataset = names[0]
        if dataset not in fh or not isinstance(fh[dataset], h5py.Dataset):
            raise ValueError(f"{file!r} has no dataset {dataset!r}; datasets: {', '.join(names[:8]) or '(none)'}")
        dset = fh[dataset]
        shape, dtype = tuple(int(n) for n in dset.shape), dset.dtype
        if dtype.kind not in "fiub":
            raise ValueError(f"{file}:{dataset} holds {dtype}, not real numbers")
        step, start, notes = _attrs_grid(dset.attrs, len(shape), f"{file}:{dataset}")
        stored = dset.chunks
    source = _H5Source(file, dataset, shape, dtype.str)
    # whole storage chunks per block (dask "auto" rounds to multiples of them)
    chunks = "auto" if stored is None else _auto_multiple(shape, stored, dtype.itemsize)
    values = da.from_array(
        source, chunks=chunks, asarray=True, fancy=False, name=f"h5-{file}-{dataset}-{os.path.getmtime(file)}"
    )
    return values, step, start, notes


def _auto_multiple(shape: tuple[int, ...], stored: tuple[int, ...], itemsize: int) -> tuple:
    from dask.array.core import normalize_chunks

    return normalize_chunks("auto", shape, dtype=np.dtype(f"V{itemsize}"), previous_chunks=stored)


def _read_zarr(store: str, inner: str) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    zarr = require("zarr", "reading zarr")
    da = require("dask.array", "reading zarr", extra="io")

    if not Path(store).exists():
        raise _missing(store, "zarr store")
    try:
        node = zarr.open(store, mode="r")
        if inner:
            node = node[inner.strip("/")]
    except KeyError:
        raise ValueError(f"{store!r} has no array {inner!r}") from None
    except Exception as exc:  # zarr raises various errors for broken stores
        raise ValueError(f"{store!r} is not a readable zarr store: {exc}") from None
    if not hasattr(node, "shape") or not hasattr(node, "dtype"):
        arrays = sorted(name for name, _ in node.arrays()) if hasattr(node, "arrays") else []
        if len(arrays) == 1:
            node = node[arrays[0]]
        else:
            raise ValueError(
                f"{store}{':' + inner if inner else ''} is a group with arrays "
                f"{arrays or '(none)'}; name one as {store}:/array"
            )
    if np.dtype(node.dtype).kind not in "fiub":
        raise ValueError(f"{store!r} holds {node.dtype}, not real numbers")
    step, start, notes = _attrs_grid(node.attrs, len(node.shape), store)
    return da.from_zarr(node), step, start, notes


# ---- NIfTI


def _nifti_open(path: str) -> tuple[Any, tuple[int, ...], np.dtype, bool]:
    """(image, shape, value dtype, scaled) from the header alone."""
    nib = require("nibabel", "reading NIfTI")

    try:
        img = nib.load(path, mmap=True)
    except Exception as exc:  # nibabel raises ImageFileError, EOFError, OSError, ValueError...
        raise ValueError(f"{path!r} is not a readable NIfTI file: {exc}") from None
    shape = tuple(int(n) for n in img.shape)
    while len(shape) > 3 and shape[-1] == 1:  # a 3D image stored with a time axis of one
        shape = shape[:-1]
    if len(shape) not in (2, 3, 4):
        raise ValueError(f"{path!r} holds a {len(shape)}D image of shape {shape}; a 2D, 3D or 4D grid is needed")
    proxy = img.dataobj
    slope, inter = getattr(proxy, "slope", 1.0), getattr(proxy, "inter", 0.0)
    scaled = not (slope is None or math.isnan(slope) or slope == 1.0) or not (
        inter is None or math.isnan(inter) or inter == 0.0
    )
    dtype = np.dtype(np.float64) if scaled else np.dtype(img.header.get_data_dtype())
    return img, shape, dtype, scaled


def _read_nifti(
    path: str, *, warn: bool = True, lazy: bool = True, scale: dict | None = None
) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    img, shape, dtype, scaled = _nifti_open(path)
    stored = np.dtype(img.header.get_data_dtype())
    if not path.lower().endswith(".gz"):
        need = int(img.dataobj.offset) + math.prod(img.shape) * stored.itemsize
        have = os.path.getsize(path)
        if have < need:
            raise ValueError(f"{path!r} is truncated: its header needs {need} bytes, the file has {have}")
        if not scaled:
            values = img.dataobj.get_unscaled().reshape(shape, order="F")  # memory map
        elif lazy:
            da = require("dask.array", "reading a scaled NIfTI lazily", extra="io")
            values = da.from_array(_NiftiSource(path, shape, dtype.str), chunks="auto", asarray=True, fancy=False)
        else:
            values = _NiftiSource(path, shape, dtype.str)[...]
    else:  # gzip cannot be sliced cheaply: decompress once
        check_memory(
            math.prod(shape) * dtype.itemsize,
            f"decompressing {path!r}",
            hint="gunzip it to .nii, which is memory-mapped",
        )
        values = _NiftiSource(path, shape, dtype.str)[...]
    scale = {} if scale is None else scale
    step, start, flips, notes = _nifti_grid(img, shape, path, warn and not scale.get("affine"), scale)
    if scale.get("affine"):
        flips = [False] * len(shape)  # the affine keeps the file's axes as they are
    if any(flips):
        values = values[tuple(slice(None, None, -1) if f else slice(None) for f in flips)]
    return values, step, start, notes


# NIfTI xyzt_units names (nibabel) -> short unit names; time units scale a w axis
_NIFTI_UNITS = {
    "mm": "mm",
    "micron": "um",
    "meter": "m",
    "sec": "s",
    "msec": "ms",
    "usec": "us",
    "hz": "Hz",
    "ppm": "ppm",
    "rads": "rad/s",
    "unknown": "unknown",
}
_TIME_UNITS = ("s", "ms", "us")


def _nifti_grid(
    img: Any, shape: tuple[int, ...], path: str, warn: bool, scale: dict | None = None
) -> tuple[np.ndarray, np.ndarray, list[bool], list[str]]:
    """(spacing, origin, flipped axes, notes) of a NIfTI image. ``scale`` (optional) passes
    ``w_scale``, ``w_step`` and ``affine`` in, and gets ``units``, ``w_scaled`` (the length per
    time unit used) and ``affine_matrix`` (index to coordinates, (d+1, d+1)) back."""
    scale = {} if scale is None else scale
    d = len(shape)
    k = min(d, 3)
    affine = np.asarray(img.affine, dtype=np.float64)
    rot = affine[:k, :k]
    zooms = np.array(img.header.get_zooms()[:d], dtype=np.float64)
    step, start = np.ones(d), np.zeros(d)
    flips = [False] * d
    notes = []
    off_diagonal = np.abs(rot - np.diag(np.diag(rot))).max()
    if off_diagonal <= 1e-6 * np.abs(rot).max() and (np.diag(rot) != 0).all():
        diag = np.diag(rot)
        for axis in range(k):
            step[axis] = abs(diag[axis])
            start[axis] = affine[axis, 3]
            if diag[axis] < 0:  # flip: the array then runs along +axis in scanner space
                flips[axis] = True
                start[axis] = affine[axis, 3] + diag[axis] * (shape[axis] - 1)
        flipped = [a for a in range(k) if flips[a]]
        notes.append(
            "spacing and origin from the axis-aligned affine"
            + (f" (axes {flipped} flipped to run along +x, +y, +z)" if flipped else "")
        )
    else:
        step[:k] = np.where(zooms[:k] > 0, zooms[:k], 1.0)
        start[:k] = affine[:k, 3]
        notes.append("oblique affine: voxel axes with the header's zooms")
        if warn:
            warnings.warn(
                f"{path!r}: the affine is oblique (not axis-aligned):\n{affine[:3, :3]}\n"
                "using the voxel axes with the header's zooms as spacing and the "
                "affine's translation as origin; the mesh is not in scanner coordinates (read "
                "it with keep_affine=True, command line --affine, to place it there)",
                ObliqueAffineWarning,
                stacklevel=5,
            )
    try:
        space_unit, time_unit = (_NIFTI_UNITS.get(u, "unknown") for u in img.header.get_xyzt_units())
    except (AttributeError, KeyError, ValueError):
        space_unit, time_unit = "unknown", "unknown"
    scale["units"] = (space_unit,) * k + ((time_unit,) if d == 4 else ())
    if d == 4:
        pixdim = float(zooms[3]) if zooms[3] > 0 else 1.0
        toffset = float(img.header.get("toffset", 0.0) or 0.0)
        if time_unit in _TIME_UNITS or time_unit in ("Hz", "ppm", "rad/s"):
            w_scale = scale.get("w_scale")
            length = space_unit if space_unit != "unknown" else "length units"
            if scale.get("w_step") is not None:
                per = scale["w_step"] / pixdim
                how = f"scaled by the w step given: {per:.6g} {length} per {time_unit}"
            elif w_scale is not None:
                per = w_scale
                how = f"scaled by w_scale: {per:.6g} {length} per {time_unit}"
            else:
                per = float(np.mean(step[:3])) / pixdim
                how = (
                    f"not taken as a length: one frame is one mean x/y/z step, "
                    f"{per * pixdim:.6g} {length} (w_scale= or --w-scale sets {length} per "
                    f"{time_unit})"
                )
            scale["w_scaled"] = per
            step[3], start[3] = pixdim * per, toffset * per
            notes.append(f"w is time: pixdim[4] = {pixdim:g} {time_unit}, toffset {toffset:g}; {how}")
        else:
            step[3], start[3] = pixdim, toffset
            notes.append(
                "w spacing from pixdim[4], origin from toffset" + (f" ({time_unit})" if time_unit != "unknown" else "")
            )
    matrix = np.eye(d + 1)
    matrix[:k, :k] = rot
    matrix[:k, d] = affine[:k, 3]
    if d == 4:
        matrix[3, 3], matrix[3, 4] = step[3], start[3]
    scale["affine_matrix"] = matrix
    if scale.get("affine"):
        notes.append("vertices placed by the file's affine (scanner coordinates)")
    return step, start, flips, notes


# ---- MetaImage

_MET_TYPES = {
    "MET_CHAR": "i1",
    "MET_UCHAR": "u1",
    "MET_SHORT": "i2",
    "MET_USHORT": "u2",
    "MET_INT": "i4",
    "MET_UINT": "u4",
    "MET_LONG": "i4",
    "MET_ULONG": "u4",
    "MET_LONG_LONG": "i8",
    "MET_ULONG_LONG": "u8",
    "MET_FLOAT": "f4",
    "MET_DOUBLE": "f8",
}


def _parse_metaimage_header(path: str) -> tuple[dict[str, str], int]:
    """Header fields and, for ``ElementDataFile = LOCAL``, the byte offset of the data."""
    fields: dict[str, str] = {}
    with open(path, "rb") as fh:
        offset = 0
        for raw in fh:
            offset += len(raw)
            try:  # file names in headers written today are UTF-8; older tools wrote latin-1
                line = raw.decode("utf-8").strip()
            except UnicodeDecodeError:
                line = raw.decode("latin-1").strip()
            if not line:
                continue
            if "=" not in line:
                raise ValueError(f"{path!r} is not a MetaImage header (line {line[:40]!r})")
            key, _, value = line.partition("=")
            fields[key.strip()] = value.strip()
            if key.strip() == "ElementDataFile":
                break
            if offset > 1 << 16:
                raise ValueError(f"{path!r} is not a MetaImage header (no ElementDataFile)")
    if "ElementDataFile" not in fields:
        raise ValueError(f"{path!r} is not a MetaImage header (no ElementDataFile)")
    return fields, offset


def _floats(fields: dict, key: str, d: int, default: float, path: str) -> np.ndarray:
    if key not in fields:
        return np.full(d, default)
    try:
        values = np.array([float(x) for x in fields[key].split()])
    except ValueError:
        raise ValueError(f"{path!r}: {key} = {fields[key]!r} is not a list of numbers") from None
    if len(values) < d:
        raise ValueError(f"{path!r}: {key} has {len(values)} entries, NDims is {d}")
    return values[:d]


def _header_int(fields: dict, key: str, default: int, path: str) -> int:
    try:
        return int(fields.get(key, str(default)))
    except ValueError:
        raise ValueError(f"{path!r}: {key} = {fields[key]!r} is not an integer") from None


def _read_metaimage(path: str, *, data: bool = True) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    """Values (a memory map; decompressed when compressed, unless ``data`` is false: then a
    read-only stand-in of the right shape and dtype), spacing, origin, notes."""
    fields, header_end = _parse_metaimage_header(path)
    try:
        d = int(fields["NDims"])
        shape = tuple(int(n) for n in fields["DimSize"].split())
    except (KeyError, ValueError):
        raise ValueError(f"{path!r}: NDims and DimSize are missing or not integers") from None
    if len(shape) != d:
        raise ValueError(f"{path!r}: DimSize has {len(shape)} entries, NDims is {d}")
    if any(n < 1 for n in shape):
        raise ValueError(f"{path!r}: DimSize = {fields['DimSize']} must be positive integers")
    met = fields.get("ElementType", "")
    if met not in _MET_TYPES:
        raise ValueError(f"{path!r}: ElementType {met!r} is not one of {', '.join(_MET_TYPES)}")
    if _header_int(fields, "ElementNumberOfChannels", 1, path) != 1:
        raise ValueError(f"{path!r}: only single-channel (scalar) images are read")
    msb = fields.get("BinaryDataByteOrderMSB", fields.get("ElementByteOrderMSB", "False"))
    dtype = np.dtype(_MET_TYPES[met]).newbyteorder(">" if msb.lower() == "true" else "<")
    data_file = fields["ElementDataFile"]
    if data_file.upper() == "LIST" or data_file.split()[0].lower().find("%") >= 0:
        raise ValueError(
            f"{path!r}: ElementDataFile = {data_file} (file lists) is not supported; give the frames as a glob instead"
        )
    if data_file.upper() == "LOCAL":
        raw, offset = path, header_end
    else:
        raw, offset = str(Path(path).parent / data_file), 0
        if not Path(raw).exists():
            raise FileNotFoundError(f"{path!r} names the data file {data_file!r}, which does not exist")
        if Path(raw).is_dir():
            raise ValueError(f"{path!r} names the data file {data_file!r}, which is a folder, not a file")
        regular_file(raw, "path", what=f"data file of {path!r}")  # a FIFO would block the reader
    header_size = _header_int(fields, "HeaderSize", 0, path)
    if header_size > 0:
        offset += header_size
    need = math.prod(shape) * dtype.itemsize
    have = os.path.getsize(raw) - offset
    # MetaImage stores x fastest: a Fortran-ordered array of shape (n_x, n_y, ...)
    if fields.get("CompressedData", "False").lower() == "true" and not data:
        values = np.broadcast_to(np.zeros((), dtype=dtype), shape)
    elif fields.get("CompressedData", "False").lower() == "true":
        check_memory(need, f"decompressing {raw!r}", hint="store the data uncompressed")
        with open(raw, "rb") as fh:
            fh.seek(offset)
            try:
                payload = zlib.decompress(fh.read())
            except zlib.error as exc:
                raise ValueError(f"{raw!r}: compressed data is corrupt or truncated ({exc})") from None
        if len(payload) != need:
            raise ValueError(f"{raw!r}: decompressed {len(payload)} bytes, DimSize needs {need}")
        values = np.frombuffer(payload, dtype=dtype).reshape(shape, order="F")
    else:
        if header_size == -1:
            offset = os.path.getsize(raw) - need
            have = need
        if have < need:
            raise ValueError(
                f"{raw!r} is truncated: DimSize {shape} of {met} needs {need} bytes "
                f"of data, the file has {max(have, 0)}"
            )
        values = np.memmap(raw, dtype=dtype, mode="r", offset=offset, shape=shape, order="F")
    step = _floats(fields, "ElementSpacing", d, 1.0, path)
    if (step <= 0).any():
        raise ValueError(f"{path!r}: ElementSpacing must be > 0, got {step.tolist()}")
    key = next((k for k in ("Offset", "Origin", "Position") if k in fields), "Offset")
    start = _floats(fields, key, d, 0.0, path)
    notes = [
        "spacing from ElementSpacing" if "ElementSpacing" in fields else "no ElementSpacing: 1",
        f"origin from {key}" if key in fields else "no Offset: 0",
    ]
    matrix_key = next((k for k in ("TransformMatrix", "Rotation", "Orientation") if k in fields), None)
    if matrix_key is not None:
        matrix = _floats(fields, matrix_key, d * d, 0.0, path).reshape(d, d)
        if np.abs(matrix - np.eye(d)).max() > 1e-6:
            warnings.warn(
                f"{path!r}: {matrix_key} is not the identity; using the voxel axes "
                "(the mesh is not in the rotated frame)",
                ObliqueAffineWarning,
                stacklevel=4,
            )
            notes.append(f"{matrix_key} ignored")
    return values, step, start, notes


# ---- VTK image data (frames)


def _vti_info(path: str) -> tuple[tuple[int, ...], np.ndarray, np.ndarray]:
    """Shape, spacing and origin from a .vti header (the data are not read)."""
    from vtkmodules.vtkCommonExecutionModel import vtkStreamingDemandDrivenPipeline
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader

    reader = vtkXMLImageDataReader()
    if not reader.CanReadFile(path):
        raise ValueError(f"{path!r} is not a readable VTK image (.vti) file")
    reader.SetFileName(path)
    reader.UpdateInformation()
    info = reader.GetOutputInformation(0)
    extent = info.Get(vtkStreamingDemandDrivenPipeline.WHOLE_EXTENT())
    if extent is None:
        raise ValueError(f"{path!r} is not a readable VTK image (.vti) file")
    shape = tuple(int(extent[2 * k + 1] - extent[2 * k] + 1) for k in range(3))
    from vtkmodules.vtkCommonDataModel import vtkDataObject

    spacing = np.array(info.Get(vtkDataObject.SPACING()) or (1.0, 1.0, 1.0), dtype=np.float64)
    origin = np.array(info.Get(vtkDataObject.ORIGIN()) or (0.0, 0.0, 0.0), dtype=np.float64)
    origin = origin + spacing * np.array([extent[0], extent[2], extent[4]])
    return shape, spacing, origin


def _vti_values(path: str) -> np.ndarray:
    pv = require("pyvista", "reading .vti frames")

    try:
        grid = pv.read(path)
    except Exception as exc:  # VTK reports broken files in several ways
        raise ValueError(f"{path!r} is not a readable VTK image (.vti): {exc}") from None
    names = [n for n in grid.point_data.keys() if np.asarray(grid.point_data[n]).ndim == 1]
    if not names or grid.n_points == 0:
        raise ValueError(f"{path!r} has no scalar point data (or is truncated)")
    name = grid.point_data.active_scalars_name if grid.point_data.active_scalars_name in names else names[0]
    data = np.asarray(grid.point_data[name])
    if data.size != math.prod(grid.dimensions):
        raise ValueError(
            f"{path!r}: point data {name!r} has {data.size} values for dimensions {grid.dimensions} (truncated?)"
        )
    return data.reshape(grid.dimensions, order="F")


def _read_vti(path: str) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    shape, step, start = _vti_info(path)
    values = _vti_values(path)
    if values.shape != shape:
        raise ValueError(f"{path!r}: data of shape {values.shape}, header says {shape}")
    return values, step, start, ["spacing and origin from the .vti header"]


# ---- globs of 3D frames


def _frame_header(path: str, kind: str, warn: bool = False) -> tuple[tuple[int, ...], np.dtype, np.ndarray, np.ndarray]:
    """Shape, dtype, spacing and origin of one frame, reading as little as the format allows."""
    regular_file(path, "path", what="frame")  # a glob may match a folder or a FIFO
    if kind == ".vti":
        shape, step, start = _vti_info(path)
        return shape, np.dtype(np.float64), step, start  # dtype: from the first frame's data
    if kind in (".mhd", ".mha"):
        with warnings.catch_warnings():
            if not warn:  # said once, for the first frame
                warnings.simplefilter("ignore", ObliqueAffineWarning)
            values, step, start, _ = _read_metaimage(path, data=False)
    elif kind == ".npy":
        values = _open_npy(path)
        step, start = np.ones(values.ndim), np.zeros(values.ndim)
    else:
        img, shape, dtype, _ = _nifti_open(path)
        step, start, _, _ = _nifti_grid(img, shape, path, warn)
        return shape, dtype, step, start
    return tuple(int(n) for n in values.shape), np.dtype(values.dtype), step, start


def _read_frames(pattern: str) -> tuple[Any, np.ndarray, np.ndarray, list[str]]:
    da = require("dask.array", "reading a glob of frames", extra="io")
    import dask

    paths = sorted(globmod.glob(pattern), key=natural_key)
    if not paths:
        raise FileNotFoundError(f"no files match {pattern!r}")
    kinds = {_suffix(p) for p in paths}
    if len(kinds) > 1:
        raise ValueError(f"{pattern!r} matches frames of different kinds: {sorted(kinds)}")
    kind = kinds.pop()
    if kind not in FRAME_SUFFIXES:
        raise ValueError(f"{pattern!r} matches {kind!r} files; frames must be one of {', '.join(FRAME_SUFFIXES)}")
    if len(paths) < 2:
        raise ValueError(f"{pattern!r} matches one frame ({paths[0]!r}); a series needs >= 2")
    shape, dtype, step, start = _frame_header(paths[0], kind, warn=True)
    if len(shape) != 3:
        raise ValueError(f"frame {paths[0]!r} is {len(shape)}D (shape {shape}); frames must be 3D")
    if kind == ".vti":
        dtype = _vti_values(paths[0]).dtype
    for path in paths[1:]:
        other = _frame_header(path, kind)[0]
        if other != shape:
            raise ValueError(f"frames of different shapes: {paths[0]!r} is {shape}, {path!r} is {other}")
    read = dask.delayed(_read_frame, pure=True)
    frames = [da.from_delayed(read(p, kind, shape, dtype.str), shape, dtype=dtype) for p in paths]
    values = da.stack(frames, axis=-1)
    notes = [
        f"{len(paths)} frames {Path(paths[0]).name} .. {Path(paths[-1]).name} stacked along w",
        "x, y, z spacing and origin from the first frame; w: 1, 0",
    ]
    return values, np.append(step, 1.0), np.append(start, 0.0), notes
