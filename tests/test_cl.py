"""OpenCL discovery: device choice and its reasons, AO4D_DEVICE, the TBB clash, the binary cache."""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from ao4d.opencl import cl
from ao4d.opencl import tbb as _tbb

LINUX_X86 = sys.platform.startswith("linux") and platform.machine() == "x86_64"


def _run(code: str, **env: str) -> subprocess.CompletedProcess:
    """Run ``code`` in a fresh interpreter with extra environment variables."""
    full = dict(os.environ, **env)
    for key, value in env.items():
        if value is None:
            full.pop(key)
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        check=False,
        capture_output=True,
        text=True,
        env=full,
        timeout=120,
    )


def _info(**env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "ao4d", "info"],
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
        env=dict(os.environ, **env),
    )


def _working() -> list[cl.DeviceReport]:
    return [r for r in cl.device_reports() if r.usable and r.kind in ("GPU", "CPU")]


def _rep(platform_name, device, kind="CPU", types=None, usable=True, reason="ok"):
    return cl.DeviceReport(
        platform=platform_name,
        device=device,
        kind=kind,
        version="OpenCL 1.2",
        compute_units=2,
        global_mem_mib=1024,
        usable=usable,
        reason=reason,
        types=types or kind,
        driver="1",
    )


POCL = _rep("Portable Computing Language", "cpu-haswell-AMD EPYC")
INTEL = _rep("Intel(R) OpenCL", "AMD EPYC")
OCLGRIND = _rep("Oclgrind", "Oclgrind Simulator", kind="OTHER", types="ACCELERATOR|GPU|CPU")
NVIDIA = _rep("NVIDIA CUDA", "NVIDIA H200", kind="GPU")
BROKEN_GPU = _rep("AMD APP", "gfx1100", kind="GPU", usable=False, reason="cannot build/run kernels: boom")


# -- discovery on this machine ----------------------------------------------------------------


def test_import_ao4d_does_not_import_pyopencl():
    out = _run("import ao4d, sys; print('pyopencl' in sys.modules)")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"


@pytest.mark.skipif(not LINUX_X86, reason="the Intel CPU runtime from PyPI is a dependency only on x86_64 Linux")
def test_a_device_works_on_this_machine():
    # this project's machines have no GPU; the Intel CPU runtime must be found and usable
    assert _working(), cl.device_reports()


def test_tiny_kernel_through_build_kernels(cl_runtime):
    import pyopencl as pcl

    kernels = cl.build_kernels(cl_runtime, "testing/selftest.cl", {"SCALE": 3})
    x = np.arange(1000, dtype=np.float32)
    buf = pcl.Buffer(cl_runtime.context, pcl.mem_flags.READ_WRITE | pcl.mem_flags.COPY_HOST_PTR, hostbuf=x)
    kernels["scale_add"](cl_runtime.queue, x.shape, None, buf, np.float32(0.5))
    out = np.empty_like(x)
    pcl.enqueue_copy(cl_runtime.queue, out, buf)
    np.testing.assert_array_equal(out, 3 * x + 0.5)
    # built once per context and options: the second call returns the same kernel objects
    assert cl.build_kernels(cl_runtime, "testing/selftest.cl", {"SCALE": 3}) is kernels


def test_build_error_shows_compiler_log(cl_runtime):
    with pytest.raises(RuntimeError, match="testing/selftest.cl") as info:
        cl.build_kernels(cl_runtime, "testing/selftest.cl", {"SCALE": "not_a_number("})
    message = str(info.value)
    log = message.split("compiler log:", 1)[1]
    assert "not_a_number" in log and "error" in log.lower(), message
    assert "source saved as" not in message  # pyopencl's temporary copy is removed


def test_missing_kernel_source(cl_runtime):
    with pytest.raises(FileNotFoundError, match="nope.cl"):
        cl.build_kernels(cl_runtime, "nope.cl")


def test_bad_prefer():
    with pytest.raises(ValueError, match="`prefer`"):
        cl.get_runtime("tpu")


def test_no_device_falls_back_with_one_warning():
    out = _run(
        """
        import warnings, ao4d.opencl.cl as c
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter('always')
            assert c.get_runtime() is None
            assert c.get_runtime() is None
        assert len(w) == 1 and issubclass(w[0].category, c.NoOpenCLDeviceWarning), w
        assert 'AO4D_DEVICE=none' in str(w[0].message), w[0].message
        """,
        AO4D_DEVICE="none",
    )
    assert out.returncode == 0, out.stderr


def test_pyopencl_imported_first_still_finds_the_bundled_runtime():
    # the ICD folder is registered even when pyopencl was imported before ao4d
    if not any(r.usable for r in cl.device_reports()):
        pytest.skip("no working OpenCL device on this machine")
    out = _run("import pyopencl; from ao4d.opencl import cl; print(cl.describe(cl.get_runtime(warn=False)))")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == cl.describe(cl.get_runtime(warn=False))


# -- backend vocabulary and the device line ---------------------------------------------------


def test_resolve_backend_checks_and_names(monkeypatch):
    with pytest.raises(ValueError, match=r"`backend` must be one of 'auto', 'opencl', 'numpy'; got 'cuda'"):
        cl.resolve_backend("cuda")
    assert cl.resolve_backend("numpy") is None
    assert cl.backend_name(None) == "numpy"
    monkeypatch.setenv("AO4D_DEVICE", "none")
    assert cl.resolve_backend("auto", warn=False) is None
    assert cl.describe(None) == "numpy (AO4D_DEVICE=none)"
    with pytest.raises(cl.NoOpenCLDeviceError, match="backend='opencl'.*AO4D_DEVICE=none"):
        cl.resolve_backend("opencl")


def test_backend_name_and_describe_of_a_runtime(cl_runtime):
    assert cl.resolve_backend("opencl") is cl_runtime
    assert cl.backend_name(cl_runtime) == "opencl"
    rep = cl_runtime.report
    assert cl.describe(cl_runtime) == f"{rep.device} ({rep.platform}, {rep.kind})" == cl_runtime.name


# -- the choice rules, on fake device reports -------------------------------------------------


@pytest.mark.parametrize(
    ("bits", "kind", "types"),
    [
        (4, "GPU", "GPU"),
        (4 | 1, "GPU", "GPU"),  # DEFAULT|GPU is still a GPU
        (2, "CPU", "CPU"),
        (8 | 4 | 2, "OTHER", "ACCELERATOR|GPU|CPU"),  # Oclgrind's simulator
        (4 | 2, "OTHER", "GPU|CPU"),
        (8, "OTHER", "ACCELERATOR"),
    ],
)
def test_kind_of_device_type_bits(bits, kind, types):
    assert cl.kind_of(bits) == (kind, types)


def test_intel_cpu_runtime_is_preferred_over_pocl():
    sel = cl.select_device([POCL, INTEL], "auto")
    assert sel.chosen is INTEL
    notes = {r.platform: why for r, why in sel.notes}
    assert notes["Intel(R) OpenCL"].startswith("chosen:") and "2-3x faster" in notes["Intel(R) OpenCL"]
    assert (
        notes["Portable Computing Language"].startswith("works, not chosen")
        and "Intel" in notes["Portable Computing Language"]
    )
    assert cl.select_device([POCL, INTEL], "cpu").chosen is INTEL
    assert cl.select_device([POCL, INTEL], "name:portable").chosen is POCL


def test_a_multi_type_device_is_not_a_gpu():
    sel = cl.select_device([OCLGRIND, INTEL], "auto")
    assert sel.chosen is INTEL
    assert "never chosen automatically" in {r.device: w for r, w in sel.notes}["Oclgrind Simulator"]
    assert cl.select_device([OCLGRIND], "auto").chosen is None
    assert cl.select_device([OCLGRIND, INTEL], "name:oclgrind").chosen is OCLGRIND
    with pytest.raises(cl.DeviceSelectionError, match="no GPU"):
        cl.select_device([OCLGRIND, INTEL], "gpu")


def test_a_gpu_comes_before_cpus_and_broken_devices_are_skipped():
    sel = cl.select_device([INTEL, BROKEN_GPU, NVIDIA], "auto")
    assert sel.chosen is NVIDIA
    notes = {r.device: w for r, w in sel.notes}
    assert notes["gfx1100"] == "skipped: cannot build/run kernels: boom"
    assert notes["AMD EPYC"] == "works, not chosen: a GPU comes first"
    assert cl.select_device([BROKEN_GPU, INTEL], "auto").chosen is INTEL
    assert cl.select_device([INTEL], "none").chosen is None


def test_gpu_request_without_a_gpu_names_the_devices_that_work():
    with pytest.raises(cl.DeviceSelectionError) as info:
        cl.select_device([POCL, INTEL, OCLGRIND], "gpu", source="AO4D_DEVICE='gpu'")
    msg = str(info.value)
    assert msg.startswith("AO4D_DEVICE='gpu': there is no GPU among the OpenCL devices")
    assert "Devices that work: AMD EPYC (Intel(R) OpenCL, CPU); cpu-haswell-AMD EPYC" in msg
    assert "Unset AO4D_DEVICE to use AMD EPYC (Intel(R) OpenCL, CPU)" in msg
    with pytest.raises(cl.DeviceSelectionError, match="no GPU device works"):
        cl.select_device([BROKEN_GPU, INTEL], "gpu")
    with pytest.raises(cl.DeviceSelectionError, match="no CPU device works"):
        cl.select_device([_rep("X", "cpu", usable=False, reason="cannot build")], "cpu")


def test_unknown_name_lists_every_device():
    with pytest.raises(cl.DeviceSelectionError) as info:
        cl.select_device([POCL, INTEL, BROKEN_GPU], "name:banana", source="AO4D_DEVICE='banana'")
    msg = str(info.value)
    assert "'banana' is not cpu, gpu or none and names no OpenCL platform or device" in msg
    for rep in (POCL, INTEL, BROKEN_GPU):
        assert f"{rep.device} | {rep.platform} | " in msg
    assert "cannot build/run kernels: boom" in msg and "AO4D_DEVICE takes cpu, gpu, none" in msg
    with pytest.raises(cl.DeviceSelectionError, match="named by 'gfx' do not work"):
        cl.select_device([BROKEN_GPU, INTEL], "name:gfx")


@pytest.mark.parametrize(
    ("value", "request_"),
    [(None, "auto"), ("", "auto"), (" GPU ", "gpu"), ("none", "none"), ("NVIDIA", "name:nvidia")],
)
def test_device_request_parsing(monkeypatch, value, request_):
    if value is None:
        monkeypatch.delenv("AO4D_DEVICE", raising=False)
    else:
        monkeypatch.setenv("AO4D_DEVICE", value)
    assert cl.device_request()[0] == request_


# -- AO4D_DEVICE in fresh processes -----------------------------------------------------------


def test_info_command_names_the_chosen_device():
    # the line must name what this process chooses (a device here, not "numpy"), and change
    # with AO4D_DEVICE: a test that fails when info reports the wrong thing
    expected = cl.describe(cl.get_runtime(warn=False))
    out = _info()
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[-1] == f"chosen: {expected}"
    if _working():
        assert not expected.startswith("numpy"), expected
        assert "      chosen: " in out.stdout  # the chosen device's own line says why
    off = _info(AO4D_DEVICE="none")
    assert off.returncode == 0, off.stderr
    assert off.stdout.splitlines()[-1] == "chosen: numpy (AO4D_DEVICE=none)"


def test_unknown_ao4d_device_is_an_error_listing_devices():
    out = _info(AO4D_DEVICE="banana")
    assert out.returncode == 2, out
    assert "AO4D_DEVICE='banana'" in out.stderr and "names no OpenCL platform or device" in out.stderr
    for rep in cl.device_reports():
        assert rep.device in out.stderr
    api = _run(
        """
        from ao4d.opencl import cl
        assert cl.resolve_backend('numpy') is None  # the numpy backend never looks at devices
        try:
            cl.resolve_backend('auto')
        except cl.DeviceSelectionError as exc:
            print('raised:', exc)
        """,
        AO4D_DEVICE="banana",
    )
    assert api.returncode == 0, api.stderr
    assert api.stdout.startswith("raised: AO4D_DEVICE='banana'")


def test_gpu_request_on_this_machine():
    working = _working()
    out = _info(AO4D_DEVICE="gpu")
    if any(r.kind == "GPU" for r in working):
        assert out.returncode == 0 and "chosen: " in out.stdout and "GPU)" in out.stdout.splitlines()[-1]
        return
    assert out.returncode == 2, out
    assert "no GPU" in out.stderr
    for rep in working:  # the CPU devices that do work are named, with what to set
        assert rep.line in out.stderr
    if working:  # and the one that unsetting AO4D_DEVICE would give
        assert f"Unset AO4D_DEVICE to use {cl.describe(cl.get_runtime(warn=False))}," in out.stderr


def test_device_chosen_by_case_insensitive_name():
    working = _working()
    if not working:
        pytest.skip("no working OpenCL device on this machine")
    target = working[-1]
    word = target.platform.split()[0].upper()
    out = _info(AO4D_DEVICE=word)
    assert out.returncode == 0, out.stderr
    last = out.stdout.splitlines()[-1]
    assert last.startswith("chosen: ") and target.platform in last


# -- a library with its own TBB loaded first (Open3D) -----------------------------------------


@pytest.fixture(scope="module")
def foreign_tbb(tmp_path_factory):
    """A stand-in for Open3D: ``libo3dlike.so`` needs ``libtbb.so.12`` and finds its own fake copy.

    The fake TBB has the soname and one real TBB function (``TBB_runtime_version``) and none of
    what Intel's runtime needs, as an older TBB lacks newer functions.
    """
    if not LINUX_X86 or _tbb.runtime_lib_dir() is None:
        pytest.skip("no bundled Intel OpenCL runtime (x86_64 Linux with intel-opencl-rt)")
    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        pytest.skip("no C compiler to build the stand-in TBB")
    if not _working():
        pytest.skip("no working OpenCL device on this machine")
    d = tmp_path_factory.mktemp("faketbb")
    (d / "t.c").write_text('const char *TBB_runtime_version(void) { return "fake-tbb-0"; }\n')
    (d / "o.c").write_text(
        "extern const char *TBB_runtime_version(void);\n"
        "const char *o3d_like_tbb(void) { return TBB_runtime_version(); }\n"
    )
    subprocess.run(
        [gcc, "-shared", "-fPIC", "-Wl,-soname,libtbb.so.12", "-o", d / "libtbb.so.12", d / "t.c"], check=True
    )
    subprocess.run(
        [gcc, "-shared", "-fPIC", "-o", d / "libo3dlike.so", d / "o.c", f"-L{d}", "-l:libtbb.so.12", f"-Wl,-rpath,{d}"],
        check=True,
    )
    return d


_LOAD_O3DLIKE = """
import ctypes
o3d = ctypes.CDLL({lib!r})
o3d.o3d_like_tbb.restype = ctypes.c_char_p
"""


def test_foreign_tbb_loaded_first_is_explained(foreign_tbb):
    code = _LOAD_O3DLIKE.format(lib=str(foreign_tbb / "libo3dlike.so")) + textwrap.dedent(
        """
        import warnings
        import ao4d, ao4d.cli
        from ao4d.opencl import cl
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter('always')
            assert cl.get_runtime() is None
        assert len(w) == 1, w
        print('WARNING', w[0].message)
        try:
            cl.resolve_backend('opencl')
        except cl.NoOpenCLDeviceError as exc:
            print('ERROR', exc)
        ao4d.cli.main(['info'])
        """
    )
    out = _run(code)
    assert out.returncode == 0, out.stderr
    fake = str(foreign_tbb / "libtbb.so.12")
    warning = next(line for line in out.stdout.splitlines() if line.startswith("WARNING"))
    error = next(line for line in out.stdout.splitlines() if line.startswith("ERROR"))
    for text in (warning, error):
        assert f"cause: {fake} was loaded into this process before ao4d" in text
        assert "libintelocl.so" in text and "undefined symbol" in text
        assert "import ao4d before that library" in text and "LD_PRELOAD=" in text
    assert f"Intel runtime's TBB: NOT loaded: another copy was loaded first: {fake}" in out.stdout
    assert "platforms that failed or disappeared in this process:" in out.stdout


def test_ao4d_imported_first_makes_both_work(foreign_tbb):
    code = (
        "import ao4d\n"
        + _LOAD_O3DLIKE.format(lib=str(foreign_tbb / "libo3dlike.so"))
        + textwrap.dedent(
            """
        from ao4d.opencl import cl
        print(cl.describe(cl.get_runtime(warn=False)))
        print(o3d.o3d_like_tbb().decode())
        """
        )
    )
    out = _run(code)
    assert out.returncode == 0, out.stderr
    device, tbb_version = out.stdout.split("\n")[:2]
    assert device == cl.describe(cl.get_runtime(warn=False))
    assert tbb_version != "fake-tbb-0"  # the stand-in runs on the runtime's (newer) TBB
    # without the preload the same order loses the device
    off = _run(code, AO4D_PRELOAD_TBB="0")
    assert off.returncode == 0, off.stderr
    assert off.stdout.split("\n")[:2] == ["numpy (no OpenCL device)", "fake-tbb-0"]


@pytest.mark.slow  # importing Open3D takes seconds; the stand-in above covers the default run
def test_open3d_either_order():
    pytest.importorskip("open3d", reason="open3d is not installed (the `bench` extra)")
    if not _working():
        pytest.skip("no working OpenCL device on this machine")
    first = _run(
        """
        import open3d, ao4d
        from ao4d.opencl import cl
        print(cl.describe(cl.get_runtime(warn=False)))
        print(' '.join(cl.platform_problems()))
        """
    )
    assert first.returncode == 0, first.stderr
    device, problems = first.stdout.split("\n")[:2]
    if device.startswith("numpy"):  # Open3D's older TBB won: it must be named, with the fix
        assert "cause: " in problems and "open3d/libtbb.so" in problems, problems
        assert "import ao4d before that library" in problems
    after = _run(
        """
        import ao4d, open3d as o3d, numpy as np
        from ao4d.opencl import cl
        print(cl.describe(cl.get_runtime(warn=False)))
        scene = o3d.t.geometry.RaycastingScene()
        sphere = o3d.geometry.TriangleMesh.create_sphere(1.0)
        scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(sphere))
        rays = np.zeros((101, 6), np.float32)
        rays[:, 0], rays[:, 1], rays[:, 3] = -5.0, np.linspace(-2.0, 2.0, 101), 1.0
        print(int(scene.test_occlusions(o3d.core.Tensor(rays)).numpy().sum()))
        """
    )
    assert after.returncode == 0, after.stderr
    device, hits = after.stdout.split("\n")[:2]
    assert device == cl.describe(cl.get_runtime(warn=False))
    # Open3D still works on the runtime's TBB: rays at |y| < 1 (minus the sphere's facets) hit
    assert 45 <= int(hits) <= 50, hits


# -- compiled kernels persist across processes ------------------------------------------------

_BUILD = """
import json, os
from ao4d.opencl import cl
rt = cl.get_runtime(warn=False)
assert rt is not None
cl.build_kernels(rt, 'testing/selftest.cl', {{'SCALE': {scale}}})
print(json.dumps(dict(cl.kernel_build_stats(), folder=str(cl.kernel_cache_dir()))))
"""


def _build_in_fresh_process(scale: int, **env: str) -> dict:
    out = _run(_BUILD.format(scale=scale), **env)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_kernel_binaries_are_reused_across_processes(cl_runtime, tmp_path):
    env = {"XDG_CACHE_HOME": str(tmp_path)}
    first = _build_in_fresh_process(3, **env)
    assert first["folder"] == str(tmp_path / "ao4d" / "kernels")
    assert (first["compiled"], first["from_cache"]) == (2, 0)  # the probe and selftest.cl
    files = sorted((tmp_path / "ao4d" / "kernels").glob("*.bin"))
    assert len(files) == 2
    second = _build_in_fresh_process(3, **env)
    assert (second["compiled"], second["from_cache"]) == (0, 2)
    # other defines are another program; the probe still comes from the cache
    other = _build_in_fresh_process(4, **env)
    assert (other["compiled"], other["from_cache"]) == (1, 1)
    # a damaged entry is dropped and rebuilt, not an error
    for f in (tmp_path / "ao4d" / "kernels").glob("*.bin"):
        f.write_bytes(b"not a binary")
    damaged = _build_in_fresh_process(3, **env)
    assert (damaged["compiled"], damaged["from_cache"]) == (2, 0)


def test_runtime_settings_are_part_of_the_binary_key(cl_runtime, tmp_path):
    # Intel's runtime compiles for CL_CONFIG_CPU_TARGET_ARCH; a binary built under one setting
    # (corei7-avx traced AO 350x slower) must not be loaded by a process without it
    env = {"XDG_CACHE_HOME": str(tmp_path)}
    plain = _build_in_fresh_process(3, **env)
    assert plain["compiled"] == 2
    other = _build_in_fresh_process(3, CL_CONFIG_AO4D_TEST_SETTING="1", **env)
    assert (other["compiled"], other["from_cache"]) == (2, 0)
    again = _build_in_fresh_process(3, **env)
    assert (again["compiled"], again["from_cache"]) == (0, 2)


def test_unwritable_cache_home_falls_back(cl_runtime, tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {"XDG_CACHE_HOME": str(blocker / "cache"), "TMPDIR": str(tmp)}  # cannot mkdir under a file
    first = _build_in_fresh_process(3, **env)
    assert first["folder"] == str(tmp / f"ao4d-kernels-{os.getuid()}")
    assert _build_in_fresh_process(3, **env)["from_cache"] == 2


def test_no_writable_cache_still_builds(cl_runtime, monkeypatch):
    from ao4d.opencl import binaries as _kernel_binaries

    monkeypatch.setattr(_kernel_binaries, "kernel_cache_dir", lambda: None)
    before = cl.kernel_build_stats()
    kernels = cl.build_kernels(cl_runtime, "testing/selftest.cl", {"SCALE": 7})
    assert "scale_add" in kernels
    after = cl.kernel_build_stats()
    assert after["compiled"] == before["compiled"] + 1 and after["from_cache"] == before["from_cache"]


def test_identical_devices_are_told_apart_by_their_place(monkeypatch):
    # two identical GPUs gave equal reports: AO4D_DEVICE could not pick the second
    first = _rep("NVIDIA CUDA", "NVIDIA H200", kind="GPU")
    second = cl.DeviceReport(**{**first.__dict__, "position": 1})
    assert first != second
    reports = [INTEL, first, second]
    for value, chosen in (
        ("gpu", first),
        ("gpu:0", first),
        ("gpu:1", second),
        ("NVIDIA:1", second),
        ("h200:0", first),
        ("cpu:0", INTEL),
    ):
        monkeypatch.setenv("AO4D_DEVICE", value)
        request, _ = cl.device_request()
        sel = cl.select_device(reports, request, source=f"AO4D_DEVICE={value!r}")
        assert sel.chosen is chosen, value
    monkeypatch.setenv("AO4D_DEVICE", "gpu:1")
    sel = cl.select_device(reports, cl.device_request()[0], source="AO4D_DEVICE='gpu:1'")
    assert "asks for match 1" in dict((id(r), why) for r, why in sel.notes)[id(first)]
    for value in ("gpu:2", "nvidia:5"):
        monkeypatch.setenv("AO4D_DEVICE", value)
        with pytest.raises(cl.DeviceSelectionError, match=r"asks for working device \d .* 2 match"):
            cl.select_device(reports, cl.device_request()[0], source=value)
    monkeypatch.setenv("AO4D_DEVICE", "none:1")
    assert cl.device_request()[0] == "none"
