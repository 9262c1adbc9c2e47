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
(:mod:`ao4d.io.volumes` writes and reads ao4d's own 3D output volumes; this module reads input
data of any origin.)
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._dask import block_sizes, is_dask_array
from .._optional import require
from .._validate import as_real, as_vector, check_bool, check_grid_lengths, regular_file
from .frames import _read_frames
from .hdf5 import _H5_SUFFIXES, _read_hdf5
from .metaimage import _read_metaimage
from .nifti import _read_nifti
from .sources import _missing, _open_npy, _suffix, _view_source
from .vti import _read_vti
from .zarr_files import _read_zarr

__all__ = ["Grid", "read_grid"]


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


def _split_inner(text: str, suffixes: tuple[str, ...]) -> tuple[str, str] | None:
    """``file.h5:/a/b`` -> (``file.h5``, ``/a/b``) for a file with one of ``suffixes``."""
    pattern = "|".join(re.escape(s) for s in suffixes)
    match = re.match(rf"^(.*?(?:{pattern}))(?::(.*))?$", text, flags=re.IGNORECASE)
    if match is None:
        return None
    return match.group(1), (match.group(2) or "")


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
