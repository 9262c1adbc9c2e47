"""Cosine-weighted hemisphere sampling in d dimensions: distribution, frames, determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy import stats

from ao4d import sampling

DIMS = (2, 3, 4)


def _unit(rng, n, d):
    v = rng.normal(size=(n, d))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _directions(d, rng_seed, n, *, samples, seed):
    """A generator seeded ``rng_seed``, ``n`` random unit normals drawn from it, and ``samples``
    cosine-weighted directions about each (n, samples, d)."""
    rng = np.random.default_rng(rng_seed)
    normals = _unit(rng, n, d)
    return rng, normals, sampling.cosine_hemisphere(normals, samples, seed=seed)


def _lowbias32(x: int) -> int:
    # C. Wellons' "lowbias32" in plain Python integers: an independent reference
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    return x ^ (x >> 16)


def test_hash_matches_reference_and_mixes():
    x = np.array([0, 1, 2, 12345, 0xFFFFFFFF], dtype=np.uint32)
    h = sampling.hash32(x)
    assert h.dtype == np.uint32
    assert h.tolist() == [_lowbias32(int(v)) for v in x]
    # avalanche: flipping one input bit flips about half of the output bits
    rng = np.random.default_rng(0)
    a = rng.integers(0, 2**32, 4096, dtype=np.uint64).astype(np.uint32)
    flips = np.unpackbits((sampling.hash32(a) ^ sampling.hash32(a ^ np.uint32(1))).view(np.uint8))
    assert abs(flips.mean() - 0.5) < 0.02  # 131k bits: standard error 0.0014


@pytest.mark.parametrize("d", DIMS)
def test_moments_match_the_cosine_density(d):
    # E[t] and E[t^2] of t = w.n under p(w) = (w.n)/|B^{d-1}| (derivation in cosine_moments):
    # 3D: 2/3, 1/2; 4D: 3 pi/16, 2/5; 2D: pi/4, 2/3
    _, normals, w = _directions(d, 10 + d, 64, samples=256, seed=3)
    t = np.einsum("nsd,nd->ns", w, normals).ravel()
    mean, second = sampling.cosine_moments(d)
    if d == 4:
        assert mean == pytest.approx(3 * math.pi / 16) and second == pytest.approx(0.4)
    if d == 3:
        assert mean == pytest.approx(2 / 3) and second == pytest.approx(0.5)
    # randomised QMC is at least as accurate as plain Monte Carlo: 4 standard errors of the
    # i.i.d. estimator (variance from the exact moments, E[t^4] <= E[t^2]) cannot fail by chance
    n = t.size
    assert abs(t.mean() - mean) < 4 * math.sqrt((second - mean**2) / n)
    assert abs((t**2).mean() - second) < 4 * math.sqrt(second / n)


@pytest.mark.parametrize("d", DIMS)
def test_cosine_cdf_is_malleys_not_normalized_sum(d):
    # P(w.n >= c) = (1 - c^2)^((d-1)/2): a uniform ball point of radius r <= sqrt(1-c^2).
    # normalize(n + u) has a different law in 4D, which this Kolmogorov-Smirnov test would see.
    rng = np.random.default_rng(20 + d)
    normals = _unit(rng, 32, d)
    t = np.einsum("nsd,nd->ns", sampling.cosine_hemisphere(normals, 128, seed=1), normals).ravel()
    cdf = lambda c: 1.0 - (1.0 - np.clip(c, 0, 1) ** 2) ** ((d - 1) / 2)  # noqa: E731
    assert stats.kstest(t, cdf).pvalue > 1e-3
    if d == 4:
        u = _unit(rng, t.size, d)
        n0 = np.repeat(normals, 128, axis=0)
        wrong = n0 + u
        wrong = np.einsum("nd,nd->n", wrong / np.linalg.norm(wrong, axis=1, keepdims=True), n0)
        assert stats.kstest(wrong[wrong > 0], cdf).pvalue < 1e-6


@pytest.mark.parametrize("d", DIMS)
def test_directions_are_unit_upper_and_symmetric_about_n(d):
    rng, normals, w = _directions(d, 30 + d, 48, samples=512, seed=5)
    np.testing.assert_allclose(np.linalg.norm(w, axis=2), 1.0, atol=1e-12)
    assert (np.einsum("nsd,nd->ns", w, normals) >= 0).all()
    # tangential part: mean zero and isotropic, E[(w.t)^2] = (1 - E[t^2]) / (d-1) for unit t
    frames = sampling.tangent_frames(normals)
    mix = _unit(rng, len(normals), d - 1)
    tang = np.einsum("nk,nkd->nd", mix, frames)  # a random unit tangent per normal
    proj = np.einsum("nsd,nd->ns", w, tang).ravel()
    var = (1 - sampling.cosine_moments(d)[1]) / (d - 1)
    n = proj.size
    assert abs(proj.mean()) < 4 * math.sqrt(var / n)
    assert abs((proj**2).mean() - var) < 4 * math.sqrt(var / n)  # E[x^4] <= E[x^2] for |x| <= 1
    # symmetry: the law of w.t equals the law of -(w.t)
    assert stats.ks_2samp(proj, -proj).pvalue > 1e-3


@settings(max_examples=60, deadline=None)
@given(
    d=st.sampled_from(DIMS),
    raw=arrays(np.float64, 4, elements=st.floats(-1e3, 1e3, allow_nan=False, allow_subnormal=False)),
)
def test_tangent_frames_are_orthonormal_and_orthogonal_to_n(d, raw):
    v = raw[:d]
    if np.linalg.norm(v) < 1e-6:
        v = np.eye(d)[-1] * (1 if v[-1] >= 0 else -1)
    n = (v / np.linalg.norm(v))[None]
    frame = sampling.tangent_frames(n)[0]
    basis = np.vstack([frame, n])
    np.testing.assert_allclose(basis @ basis.T, np.eye(d), atol=1e-12)


def test_deterministic_per_seed_and_chunkable():
    rng = np.random.default_rng(40)
    normals = _unit(rng, 20, 4)
    a = sampling.cosine_hemisphere(normals, 64, seed=9)
    np.testing.assert_array_equal(a, sampling.cosine_hemisphere(normals, 64, seed=9))
    assert not np.allclose(a, sampling.cosine_hemisphere(normals, 64, seed=10))
    # chunks with index_offset reproduce one call
    b = np.concatenate(
        [
            sampling.cosine_hemisphere(normals[:7], 64, seed=9),
            sampling.cosine_hemisphere(normals[7:], 64, seed=9, index_offset=7),
        ]
    )
    np.testing.assert_array_equal(a, b)


def test_neighbouring_points_do_not_share_directions():
    # identical normals at consecutive indices must still get different direction sets
    normals = np.tile([[0.0, 0.0, 0.0, 1.0]], (8, 1))
    w = sampling.cosine_hemisphere(normals, 16, seed=0)
    for i in range(7):
        assert np.abs(w[i] - w[i + 1]).max() > 0.1


def test_ball_points_are_uniform():
    # radius law P(|b| <= s) = s^k for a uniform point of the unit k-ball
    rng = np.random.default_rng(50)
    for k in (1, 2, 3):
        b = sampling.ball_points(rng.random((20000, k)))
        r = np.linalg.norm(b, axis=1)
        assert r.max() <= 1.0
        assert stats.kstest(r, lambda s, k=k: np.clip(s, 0, 1) ** k).pvalue > 1e-3
    with pytest.raises(ValueError, match="1 to 3"):
        sampling.ball_points(np.zeros((3, 4)))


def test_bad_inputs():
    with pytest.raises(ValueError, match="samples"):
        sampling.cosine_hemisphere([[0.0, 0, 1]], 0)
    with pytest.raises(ValueError, match="normals"):
        sampling.cosine_hemisphere([[0.0, 0, 0, 0, 1]], 4)
    with pytest.raises(ValueError, match="normals"):
        sampling.cosine_hemisphere([[np.nan, 0, 1]], 4)
    with pytest.raises(TypeError, match="samples"):
        sampling.cosine_hemisphere([[0.0, 0, 1]], 2.5)


@pytest.mark.parametrize("d", DIMS)
def test_opencl_directions_equal_numpy(cl_runtime, d):
    from ao4d.rays import launches

    rng = np.random.default_rng(60 + d)
    normals = _unit(rng, 40, d)
    dev = launches.sample_directions(cl_runtime, normals, 37, 11)
    host = sampling.cosine_hemisphere(normals, 37, seed=11)
    # same integers and formulas; float32 trigonometry and frame: a few ulp of 1
    np.testing.assert_allclose(dev, host, atol=1e-5)


def test_sobol_tables_are_kept_across_processes(tmp_path, monkeypatch):
    import os
    import subprocess
    import sys

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    sampling._sobol_cached.cache_clear()
    try:
        fresh = sampling._sobol_compute(40, 3, 5)
        first = sampling.sobol_table(40, 3, seed=5)
        assert np.array_equal(first, fresh)
        # kept as the next power of two (64), whose prefix is the same sequence
        kept = list((tmp_path / "ao4d" / "sobol").glob("sobol-64-3-5-*.npy"))
        assert len(kept) == 1 and np.array_equal(np.load(kept[0])[:40], fresh)
        # another process reads the file and never imports scipy.stats (0.6-1.2 s)
        code = (
            "import sys; from ao4d import sampling; t = sampling.sobol_table(40, 3, seed=5); "
            "print(int(t.sum()), 'scipy.stats' in sys.modules)"
        )
        out = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, "XDG_CACHE_HOME": str(tmp_path)},
        ).stdout.split()
        assert out == [str(int(fresh.sum())), "False"]
        # a damaged or foreign file is computed again and replaced
        for damage in (b"not a table", None):
            if damage is None:
                np.save(kept[0], np.zeros((64, 2), np.uint32))  # wrong shape
            else:
                kept[0].write_bytes(damage)
            sampling._sobol_cached.cache_clear()
            assert np.array_equal(sampling.sobol_table(40, 3, seed=5), fresh)
            assert np.array_equal(np.load(kept[0])[:40], fresh)
    finally:
        sampling._sobol_cached.cache_clear()


def test_sobol_tables_work_without_a_writable_cache(tmp_path, monkeypatch):
    from ao4d.opencl import binaries as _kernel_binaries

    monkeypatch.setattr(_kernel_binaries, "cache_dir", lambda kind: None)
    sampling._sobol_cached.cache_clear()
    try:
        assert np.array_equal(sampling.sobol_table(24, 2, seed=1), sampling._sobol_compute(24, 2, 1))
    finally:
        sampling._sobol_cached.cache_clear()
