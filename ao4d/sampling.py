"""Cosine-weighted hemisphere directions in d dimensions, identical on the numpy and OpenCL backends.

Malley's method in d dimensions: a point ``b`` drawn uniformly from the unit (d-1)-ball of the
tangent hyperplane of ``n`` is lifted onto the hemisphere, ``w = b + sqrt(1 - |b|^2) n``. The
projection of the cosine-weighted density ``(w . n) / |B^{d-1}|`` onto the tangent hyperplane is
uniform on the ball (the cosine is the Jacobian of the lift), so this is exact in every dimension.
(``normalize(n + u)`` with ``u`` on the sphere is cosine-weighted only in 3D.)

The ball points come from one scrambled Sobol table ``(samples, d-1)`` shared by all points. Each
point shifts it by its own Cranley-Patterson offset, taken from a counter-based integer hash of
``(seed, point index, coordinate)``, so neighbouring points never share directions and any backend
reproduces them exactly: the table and the offsets are 24-bit integers added modulo 2^24, then
mapped to ``(0, 1)`` exactly in float32 and float64 alike.

The tangent frame of ``n`` is the Householder reflection that swaps ``n`` with ``-sign(n_last)``
times the last axis (the d-dimensional form of Duff et al.'s branchless frame): its other columns
``t_j = e_j - n_j (n + s e_last) / (1 + |n_last|)`` are orthonormal and orthogonal to ``n``.

References
----------
Malley's method: M. Pharr, W. Jakob, G. Humphreys, *Physically Based Rendering*, 3rd ed., 13.6.3.
T. Duff et al., *Building an orthonormal basis, revisited*, JCGT 6(1), 2017.
R. Cranley, T. N. L. Patterson, *Randomization of number theoretic methods for multiple
integration*, SIAM J. Numer. Anal. 13(6), 1976, doi:10.1137/0713071.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from ._validate import as_array, check_positive_int, check_seed

__all__ = [
    "hash32",
    "point_shifts",
    "sobol_table",
    "tangent_frames",
    "ball_points",
    "cosine_hemisphere",
    "cosine_moments",
]

BITS = 24  # resolution of the sample coordinates: exact in float32
_MASK = np.uint32((1 << BITS) - 1)
_SCALE = 1.0 / (1 << BITS)


def hash32(x: np.ndarray) -> np.ndarray:
    """Integer hash of uint32 values ("lowbias32", C. Wellons); ``kernels/common/sampling.h`` matches it.

    Parameters
    ----------
    x : (...) uint32
        The values.

    Returns
    -------
    (...) uint32
        Their hashes.
    """
    x = np.asarray(x, dtype=np.uint32).copy()
    x ^= x >> np.uint32(16)
    x *= np.uint32(0x7FEB352D)
    x ^= x >> np.uint32(15)
    x *= np.uint32(0x846CA68B)
    x ^= x >> np.uint32(16)
    return x


def point_shifts(index: np.ndarray, seed: int, ndim: int) -> np.ndarray:
    """Per-point Cranley-Patterson offsets, 24-bit integers.

    Parameters
    ----------
    index : (N,) int
        Global point indices (the counter of the hash).
    seed : int
        The seed of the hash.
    ndim : int
        Number of coordinates per offset (d - 1).

    Returns
    -------
    shifts : (N, ndim) uint32
        Values in ``[0, 2^24)``.
    """
    index = np.asarray(index).astype(np.uint32)  # wraps above 2^32 points, like the kernel
    base = hash32(hash32(index) ^ np.uint32(seed & 0xFFFFFFFF))
    k = np.arange(ndim, dtype=np.uint32)
    return hash32(base[:, None] + k[None, :]) >> np.uint32(32 - BITS)


@lru_cache(maxsize=32)
def _sobol_cached(samples: int, ndim: int, seed: int) -> np.ndarray:
    path = _sobol_file(samples, ndim, seed)
    table = _read_table(path, samples, ndim) if path is not None else None
    if table is None:
        table = _sobol_compute(samples, ndim, seed)
        if path is not None:
            from ._atomic import atomic_open

            try:
                with atomic_open(path, "wb") as fh:
                    np.save(fh, table)
            except OSError:  # read-only or full disk: computed again next time
                pass
    table.setflags(write=False)
    return table


def _sobol_compute(samples: int, ndim: int, seed: int) -> np.ndarray:
    from scipy.stats import qmc

    # random_base2 avoids scipy's warning for non-powers of two; a prefix keeps low discrepancy
    m = max(0, math.ceil(math.log2(samples)))
    pts = qmc.Sobol(ndim, scramble=True, seed=seed).random_base2(m)[:samples]
    return np.floor(pts * (1 << BITS)).astype(np.uint32)


def _sobol_file(samples: int, ndim: int, seed: int) -> Path | None:
    """Where the table is kept across processes (importing scipy.stats costs 0.6-1.2 s, most of
    what a first AO call on a 1M-tet mesh spends tracing), or None; keyed by scipy's version,
    whose scrambling defines the table."""
    from importlib.metadata import PackageNotFoundError, version

    from .opencl.binaries import cache_dir

    folder = cache_dir("sobol")
    try:
        scipy_version = version("scipy")
    except PackageNotFoundError:
        return None
    if folder is None:
        return None
    return folder / f"sobol-{samples}-{ndim}-{seed}-{BITS}-scipy{scipy_version}.npy"


def _read_table(path: Path, samples: int, ndim: int) -> np.ndarray | None:
    """The kept table, or None when it is missing or not a table of this shape (damaged)."""
    try:
        table = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None
    ok = table.shape == (samples, ndim) and table.dtype == np.uint32 and (table < (1 << BITS)).all()
    return table if ok else None


def sobol_table(samples: int, ndim: int, *, seed: int = 0) -> np.ndarray:
    """The shared scrambled Sobol points as 24-bit integers.

    Parameters
    ----------
    samples : int
        Number of points.
    ndim : int
        Coordinates per point.
    seed : int
        Seed of the scrambling, in ``[0, 2**32)``.

    Returns
    -------
    table : (samples, ndim) uint32, read-only
        Values in ``[0, 2^24)``; coordinate k of sample j is ``(table[j, k] + 0.5) / 2^24``.
    """
    samples = check_positive_int(samples, "samples")
    # computed (and kept) as the next power of two: its prefix is the same scrambled sequence,
    # and the rounds of AO to a tolerance, which read growing prefixes, share one table
    whole = _sobol_cached(1 << max(0, math.ceil(math.log2(samples))), int(ndim), check_seed(seed))
    return whole if len(whole) == samples else whole[:samples]


def tangent_frames(normals: np.ndarray) -> np.ndarray:
    """Orthonormal tangent vectors of unit normals (Householder frame, see module docstring).

    Parameters
    ----------
    normals : (N, d) float64
        Unit vectors.

    Returns
    -------
    frames : (N, d-1, d) float64
        ``frames[i, j]`` is the j-th tangent vector of ``normals[i]``.
    """
    n = np.asarray(normals, dtype=np.float64)
    d = n.shape[-1]
    s = np.where(n[:, -1] >= 0.0, 1.0, -1.0)
    v = n.copy()
    v[:, -1] += s
    a = 1.0 / (1.0 + np.abs(n[:, -1]))
    frames = -(n[:, : d - 1, None] * a[:, None, None]) * v[:, None, :]
    frames[:, np.arange(d - 1), np.arange(d - 1)] += 1.0
    return frames


def ball_points(u: np.ndarray) -> np.ndarray:
    """Map points of the unit cube ``(0,1)^k`` to uniform points of the unit k-ball, k in {1,2,3}.

    Radius ``u0^(1/k)``; the direction on S^(k-1) from the remaining coordinates (the sign for
    k = 1, an angle for k = 2, Archimedes' z = 1 - 2 u1 and an angle for k = 3).

    Parameters
    ----------
    u : (N, k) float64 numpy.ndarray
        Points of the open unit cube.

    Returns
    -------
    (N, k) float64 numpy.ndarray
        Points of the unit k-ball.
    """
    u = np.asarray(u, dtype=np.float64)
    k = u.shape[-1]
    if k == 1:
        return 2.0 * u - 1.0
    if k == 2:
        r = np.sqrt(u[..., 0])
        phi = 2.0 * np.pi * u[..., 1]
        return np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)
    if k == 3:
        r = np.cbrt(u[..., 0])
        z = 1.0 - 2.0 * u[..., 1]
        s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        phi = 2.0 * np.pi * u[..., 2]
        return np.stack([r * s * np.cos(phi), r * s * np.sin(phi), r * z], axis=-1)
    raise ValueError(f"ball points are implemented for 1 to 3 dimensions, got {k}")


def cosine_hemisphere(
    normals: np.ndarray,
    samples: int,
    *,
    seed: int = 0,
    index_offset: int = 0,
    index: np.ndarray | None = None,
    first: int = 0,
) -> np.ndarray:
    """Cosine-weighted directions on the hemisphere around each normal.

    Parameters
    ----------
    normals : (N, d) array_like
        Unit normals, d in {2, 3, 4}.
    samples : int
        Directions per normal.
    seed : int
        Seeds both the Sobol scrambling and the per-point offsets, in ``[0, 2**32)``.
    index_offset : int
        Global index of ``normals[0]``: point i uses the offsets of ``index_offset + i``, so a
        chunked computation reproduces the directions of a single call.
    index : (N,) int, optional
        Global indices of the normals (instead of ``index_offset + arange(N)``): a point's
        directions depend only on ``seed`` and its index, whichever points are traced with it.
    first : int
        Start at row ``first`` of the Sobol table: directions ``first`` to
        ``first + samples - 1`` of each point's sequence.

    Returns
    -------
    directions : (N, samples, d) float64
        Unit vectors with ``directions . normal > 0`` (up to float rounding at the rim).

    Examples
    --------
    >>> w = cosine_hemisphere(np.array([[0.0, 0, 0, 1]]), 4096, seed=1)
    >>> round(float(w[0, :, 3].mean()), 2)  # E[cos] = 3 pi / 16 in 4D
    0.59
    """
    n = as_array(normals, "normals", ndim=2, dtype=np.float64, finite=True)
    d = n.shape[1]
    if d not in (2, 3, 4):
        raise ValueError(f"`normals` must have 2, 3 or 4 columns, got {d}")
    seed = check_seed(seed)
    table = sobol_table(first + samples, d - 1, seed=seed)[first:]
    index = np.arange(index_offset, index_offset + len(n)) if index is None else np.asarray(index)
    shifts = point_shifts(index, seed, d - 1)
    u_int = (table[None, :, :] + shifts[:, None, :]) & _MASK
    u = (u_int.astype(np.float64) + 0.5) * _SCALE
    b = ball_points(u)  # (N, samples, d-1)
    frames = tangent_frames(n)  # (N, d-1, d)
    up = np.sqrt(np.maximum(0.0, 1.0 - np.einsum("nsk,nsk->ns", b, b)))
    return np.einsum("nsk,nkd->nsd", b, frames) + up[..., None] * n[:, None, :]


def cosine_moments(d: int) -> tuple[float, float]:
    """Exact ``E[w·n]`` and ``E[(w·n)^2]`` under the cosine-weighted hemisphere density in R^d.

    With ``t = w . n = sqrt(1 - r^2)`` and ``r^(d-1)`` uniform on (0, 1) (Malley):
    ``E[t] = (d-1) * integral_0^1 r^(d-2) sqrt(1 - r^2) dr = (d-1)/2 * B((d-1)/2, 3/2)`` and
    ``E[t^2] = 1 - E[r^2] = 1 - (d-1)/(d+1) = 2/(d+1)``. In 3D: 2/3 and 1/2; in 4D: 3 pi/16 and 2/5.

    Parameters
    ----------
    d : int
        The dimension.

    Returns
    -------
    tuple of float
        ``E[w·n]`` and ``E[(w·n)^2]``.
    """
    k = d - 1
    mean = k / 2 * math.gamma(k / 2) * math.gamma(1.5) / math.gamma(k / 2 + 1.5)
    return mean, 2.0 / (d + 1)
