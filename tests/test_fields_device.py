"""Tests for ao4d.marching.fields_device: the shape library's fields sampled on the OpenCL device.

The device's values are compared with the host's (ao4d.fields.evaluate_layers, numpy) by
``np.array_equal`` for every kind of field and composition, on grids in 2D, 3D and 4D, at
extreme coordinates too (hypot's scaled branches, overflow to infinity); the one node with the
device's own transcendental functions that differs (gyroid's sin, cos) is held to the stated
bound. extract_field's meshes with device sampling are the host-sampled meshes array for array,
on the device engine and on the numpy engine; fields that cannot go to the device (plain
callables, a plain callable inside a composition, a dimension mismatch), devices without fp64
(forced: ao4d.marching.cells_device.FLOAT32) and backend="numpy" keep host sampling.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import ao4d
from ao4d import fields
from ao4d.marching import cells_device, fields_device


def _exact():
    if not fields_device.host_matches()["exact"]:
        pytest.skip(f"this host's numpy is not mirrored exactly: {fields_device.host_matches()}")


def _fp64(runtime):
    if "cl_khr_fp64" not in runtime.device.extensions:
        pytest.skip("the OpenCL device has no cl_khr_fp64: fields are sampled on the host")
    return runtime


CASES_4D = {
    "hypersphere": fields.hypersphere(0.9, [0.1, -0.2, 0.05, 0.3]),
    "spheritorus": fields.spheritorus(1.0, 0.4),
    "torisphere": fields.torisphere(1.0, 0.35),
    "ditorus": fields.ditorus(),
    "tiger": fields.tiger(),
    "duocylinder": fields.duocylinder(0.9, 0.6),
    "tesseract": fields.tesseract(0.9),
    "rounded tesseract": fields.tesseract(1.0, 0.3),
    "indented_cube": fields.indented_cube(1.0, 0.6),
    "metaballs": fields.preset("metaballs"),
    "ground in a ball": fields.intersection(fields.ground(0.2), fields.hypersphere(1.2)),
    "union of three": fields.union(
        fields.duocylinder(0.8, 0.6), fields.hypersphere(0.5, [1, 0, 0, 0]), fields.spheritorus()
    ),
    "difference": fields.difference(fields.torisphere(), fields.tesseract(0.5, 0.1)),
    "smooth union": fields.smooth_union(fields.hypersphere(0.6, [0.3, 0, 0, 0]), fields.ditorus(), 0.3),
    "rotate translate scale": fields.rotate(
        fields.translate(fields.scale(fields.tiger(), 1.3), [0.1, 0.2, -0.1, 0.05]), (1, 3), 0.7
    ),
    "rotations in every plane": fields.rotate(
        fields.rotate(
            fields.rotate(
                fields.rotate(
                    fields.rotate(fields.rotate(fields.tesseract(0.8, 0.1), (0, 1), 0.3), (0, 2), -0.4), (0, 3), 0.5
                ),
                (1, 2),
                0.6,
            ),
            (1, 3),
            -0.7,
        ),
        (2, 3),
        0.8,
    ),
    "nested": fields.intersection(
        fields.smooth_union(
            fields.scale(fields.spheritorus(), 0.8),
            fields.metaballs([[0.5, 0, 0, 0], [-0.5, 0.2, 0, 0]], [0.4, 0.3], sharpness=3.0),
            0.2,
        ),
        fields.difference(fields.hypersphere(1.4), fields.translate(fields.ditorus(), [0, 0, 0.3, 0])),
    ),
}
CASES_LOW = {
    2: [
        fields.hypersphere(0.8, [0.1, 0.2]),
        fields.tesseract(0.7, 0.2, dim=2),
        fields.union(fields.ground(0.1, 0, dim=2), fields.hypersphere(0.3, [0.5, 0.5])),
        fields.metaballs([[0.2, 0.1], [-0.3, 0]], 0.4),
        fields.rotate(fields.translate(fields.tesseract(0.5, dim=2), [0.1, 0]), (0, 1), 0.4),
    ],
    3: [
        fields.hypersphere(0.8, [0.1, 0.2, -0.1]),
        fields.tesseract(0.7, 0.2, dim=3),
        fields.scale(fields.metaballs([[0.2, 0.1, 0], [-0.3, 0, 0.2]], 0.4), 1.2),
        fields.difference(fields.tesseract(0.8, dim=3), fields.ground(0.3, 2, dim=3)),
    ],
}


def _axes(d, n=(9, 8, 7, 6), lo=-1.7, hi=1.6):
    return fields.grid_axes(n[:d], (lo, hi))


@pytest.mark.parametrize("name", sorted(CASES_4D))
def test_every_field_kind_is_sampled_bit_for_bit(cl_runtime, name):
    _fp64(cl_runtime)
    _exact()
    field = CASES_4D[name]
    axes = _axes(4)
    host = fields.evaluate_layers(field, axes, 0, len(axes[-1]))
    dev = fields_device.sample_layers(field, axes, 0, len(axes[-1]), cl_runtime)
    assert dev.shape == host.shape
    np.testing.assert_array_equal(dev, host)
    # a range of layers in the middle: the same as those layers of the whole
    np.testing.assert_array_equal(fields_device.sample_layers(field, axes, 2, 5, cl_runtime), host[2:5])


@pytest.mark.parametrize("d", [2, 3])
def test_two_and_three_dimensional_fields_are_sampled_bit_for_bit(cl_runtime, d):
    _fp64(cl_runtime)
    _exact()
    axes = _axes(d, (13, 11, 9))
    for field in CASES_LOW[d]:
        host = fields.evaluate_layers(field, axes, 0, len(axes[-1]))
        dev = fields_device.sample_layers(field, axes, 0, len(axes[-1]), cl_runtime)
        np.testing.assert_array_equal(dev, host, err_msg=repr(field))


def test_extreme_coordinates_take_hypots_scaled_branches_bit_for_bit(cl_runtime):
    """Coordinates from 1e-310 (subnormal) to 1e300 (squares overflow): glibc's hypot branches
    for huge and tiny arguments, infinities, zeros of both signs."""
    _fp64(cl_runtime)
    _exact()
    coords = np.array(
        [-1e300, -3e200, -1e160, -2.0, -2.5e-300, -1e-200, -0.0, 0.0, 1e-310, 1e-300, 3e-170, 1e-9, 0.7, 1e154, 5e250]
    )
    axes = [coords, coords[::2], coords[1::2], coords[3:11]]
    tiny = (fields.duocylinder(1e-300, 2e-300), fields.tiger(1e-300, 2e-300, 5e-301))
    for field in (
        fields.spheritorus(1.0, 0.4),
        fields.ditorus(),
        fields.tiger(),
        fields.duocylinder(),
        fields.scale(fields.tiger(), 1e70),
        *tiny,
    ):
        with np.errstate(all="ignore"):
            host = fields.evaluate_layers(field, axes, 0, len(axes[-1]))
        dev = fields_device.sample_layers(field, axes, 0, len(axes[-1]), cl_runtime)
        np.testing.assert_array_equal(dev, host, err_msg=repr(field))


def test_glibc_hypot_mirror_matches_numpy_on_edge_values():
    """The Python twin of the kernel's np_hypot (the probe's reference) on the branches."""
    if not fields_device.host_matches()["hypot"]:
        pytest.skip("this host's np.hypot is not glibc's")
    vals = [0.0, 1e-320, 1e-300, 2.0**-459, 3e-155, 1e-20, 0.5, 1.0, 3.0, 1e20, 2.0**511, 1e300, 1.7e308]
    for x in vals:
        for y in vals:
            with np.errstate(over="ignore"):
                assert fields_device._glibc_hypot(x, y) == np.hypot(x, y), (x, y)


def test_gyroid_is_within_the_stated_bound(cl_runtime):
    """sin and cos are the device's: not numpy's bits, within TRANSCENDENTAL_ULPS ulp of 1."""
    _fp64(cl_runtime)
    rng = np.random.default_rng(7)
    axes = [np.sort(rng.uniform(-2, 2, n)) for n in (11, 12, 13, 14)]
    for field in (fields.gyroid(0.7, 0.3), fields.preset("gyroid")):
        host = fields.evaluate_layers(field, axes, 0, 14)
        dev = fields_device.sample_layers(field, axes, 0, 14, cl_runtime)
        err = np.abs(dev - host).max() / np.spacing(1.0)
        assert err <= fields_device.TRANSCENDENTAL_ULPS, err


def test_gyroid_meshes_agree_within_the_bound(cl_runtime, monkeypatch):
    """A generic level: the same simplices, vertices within a few ulp of the grid's scale."""
    _fp64(cl_runtime)
    field = fields.preset("gyroid")
    dev = ao4d.extract_field(field, 14, (-1.1, 1.1), 0.0123, progress=False)
    monkeypatch.setattr(fields_device, "reader", lambda f, axes, backend, read, **kw: read)
    host = ao4d.extract_field(field, 14, (-1.1, 1.1), 0.0123, progress=False)
    np.testing.assert_array_equal(dev.simplices, host.simplices)
    assert np.abs(dev.vertices - host.vertices).max() < 1e-12


def test_fields_without_a_device_program_stay_on_the_host():
    def plain(p):
        return np.linalg.norm(p, axis=-1) - 1.0

    wrapped = fields.Field(plain, dim=4, name="plain")
    for field in (
        plain,
        wrapped,
        fields.union(fields.hypersphere(1.0), plain),
        fields.rotate(fields.translate(plain, [0, 0, 0, 1]), (0, 1), 0.2),
    ):
        assert fields_device.device_source(field, 4) is None
    # dimension mismatches: the host raises its own error
    assert fields_device.device_source(fields.spheritorus(), 3) is None
    assert fields_device.device_source(fields.hypersphere(1.0, dim=3), 4) is None
    assert fields_device.device_source(fields.ground(0.0, 1, dim=3), 4) is None
    assert fields_device.device_source(fields.metaballs([[0, 0, 0]], 0.5), 4) is None
    source, params = fields_device.device_source(fields.spheritorus(1.0, 0.4), 4)
    assert "field_value" in source and params.tolist() == [1.0, 0.4]


def test_sample_layers_refuses_what_it_cannot_sample(cl_runtime):
    _fp64(cl_runtime)
    axes = _axes(4)
    with pytest.raises(ValueError, match="`field`.*no device program"):
        fields_device.sample_layers(lambda p: p[..., 0], axes, 0, 2, cl_runtime)
    with pytest.raises(ValueError, match="`start`, `stop`"):
        fields_device.sample_layers(fields.spheritorus(), axes, 3, 99, cl_runtime)


def _spy_host(monkeypatch):
    """Count the layers extract_field samples on the host."""
    calls = []
    original = fields.evaluate_layers

    def spy(field, axes, start, stop):
        calls.append((start, stop))
        return original(field, axes, start, stop)

    monkeypatch.setattr(fields, "evaluate_layers", spy)
    return calls


def _host_sampled(monkeypatch, *args, **kwargs):
    with monkeypatch.context() as m:
        m.setattr(fields_device, "reader", lambda f, axes, backend, read, **kw: read)
        return ao4d.extract_field(*args, **kwargs)


@pytest.mark.parametrize("method", ["cubes", "simplices"])
@pytest.mark.parametrize("chunk", [None, 1, 3])
def test_extract_field_meshes_are_the_host_sampled_ones(cl_runtime, monkeypatch, method, chunk):
    """Device slabs sampled in place: the same arrays as host sampling, in one slab and many."""
    _fp64(cl_runtime)
    _exact()
    field = fields.rotate(fields.spheritorus(1.0, 0.4), (0, 3), 0.3)
    shape, bounds = (13, 12, 11, 14), (-1.5, 1.5)
    calls = _spy_host(monkeypatch)
    dev = ao4d.extract_field(field, shape, bounds, 0.01, method=method, chunk=chunk, progress=False)
    assert calls == []  # nothing sampled on the host
    host = _host_sampled(monkeypatch, field, shape, bounds, 0.01, method=method, chunk=chunk, progress=False)
    assert calls and dev.n_simplices > 0
    np.testing.assert_array_equal(dev.vertices, host.vertices)
    np.testing.assert_array_equal(dev.simplices, host.simplices)


@pytest.mark.parametrize("d", [2, 3])
def test_extract_field_in_2d_and_3d(cl_runtime, monkeypatch, d):
    _fp64(cl_runtime)
    _exact()
    for field in CASES_LOW[d]:
        dev = ao4d.extract_field(field, 17, (-1.2, 1.1), progress=False)
        host = _host_sampled(monkeypatch, field, 17, (-1.2, 1.1), progress=False)
        np.testing.assert_array_equal(dev.vertices, host.vertices)
        np.testing.assert_array_equal(dev.simplices, host.simplices)


def test_the_numpy_engine_gets_device_sampled_host_arrays(cl_runtime, monkeypatch):
    """Where the device engine cannot take the slab (forced), the numpy engine marches the
    device's values, downloaded: the same mesh as backend='numpy'."""
    _fp64(cl_runtime)
    _exact()
    field = fields.preset("tiger")
    ref = ao4d.extract_field(field, 12, (-1.3, 1.3), method="simplices", backend="numpy", progress=False)
    calls = _spy_host(monkeypatch)
    monkeypatch.setattr(cells_device, "fits", lambda *a: False)
    got = ao4d.extract_field(field, 12, (-1.3, 1.3), method="simplices", progress=False)
    assert calls == []
    np.testing.assert_array_equal(got.vertices, ref.vertices)
    np.testing.assert_array_equal(got.simplices, ref.simplices)


def test_without_fp64_or_with_backend_numpy_fields_are_sampled_on_the_host(cl_runtime, monkeypatch):
    """cells_device.FLOAT32 is the path of devices without cl_khr_fp64: host sampling, and the
    mesh is the one of the float32 path with host-sampled values."""
    field = fields.spheritorus(1.0, 0.4)
    calls = _spy_host(monkeypatch)
    ao4d.extract_field(field, 9, (-1.5, 1.5), backend="numpy", progress=False)
    assert calls
    calls.clear()
    monkeypatch.setattr(cells_device, "FLOAT32", True)
    assert not fields_device.usable(cl_runtime)
    got = ao4d.extract_field(field, 11, (-1.5, 1.5), progress=False)
    assert calls
    ref = _host_sampled(monkeypatch, field, 11, (-1.5, 1.5), progress=False)
    np.testing.assert_array_equal(got.vertices, ref.vertices)
    np.testing.assert_array_equal(got.simplices, ref.simplices)


def test_non_finite_values_are_reported_as_host_sampling_reports_them(cl_runtime, monkeypatch):
    """exp overflows to infinity near the centres of very sharp metaballs: the same error."""
    _fp64(cl_runtime)
    field = fields.metaballs([[0.0, 0.0, 0.0, 0.1]], 0.5, sharpness=800.0)
    with np.errstate(all="ignore"):
        with pytest.raises(ValueError, match="`field` returned .* non-finite") as dev:
            ao4d.extract_field(field, 9, (-1.0, 1.0), progress=False)
        with pytest.raises(ValueError, match="`field` returned .* non-finite") as host:
            _host_sampled(monkeypatch, field, 9, (-1.0, 1.0), progress=False)
    assert str(dev.value) == str(host.value)


def test_the_inside_out_warning_reads_the_device_sampled_corner(cl_runtime):
    """extract_field's inside-out check needs the grid's first value: the device gives it."""
    _fp64(cl_runtime)
    with pytest.warns(ao4d.mesh.InsideOutWarning):
        ao4d.extract_field(fields.hypersphere(1.0), 9, (-1.3, 1.3), inside="above", progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", ao4d.mesh.InsideOutWarning)
        ao4d.extract_field(fields.hypersphere(1.0), 9, (-1.3, 1.3), progress=False)


def test_host_matches_reports_the_probes():
    found = fields_device.host_matches()
    assert set(found) == {"lanes", "einsum", "hypot", "exact"}
    assert found["lanes"] in (1, 2)
    assert found["exact"] == (found["einsum"] and found["hypot"])
