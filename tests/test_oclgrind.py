"""Every OpenCL kernel of ao4d on tiny scenes under Oclgrind, the OpenCL simulator that checks
each memory access (out-of-bounds reads and writes are always reported), the API calls
(``OCLGRIND_CHECK_API``) and data races between work-items (``OCLGRIND_DATA_RACES``).

Oclgrind registers no ICD: the test writes one in a temporary folder, points ``OCL_ICD_VENDORS``
at it and selects the simulator with ``AO4D_DEVICE`` in a subprocess that runs
``tests/_oclgrind_check.py`` (answers checked there against brute force and numpy).

Not enabled: ``OCLGRIND_UNINITIALIZED``. In Oclgrind 21.10 that experimental plugin reports every
store of a vector literal such as ``out[0] = (int2)(a, b)`` as "uninitialized value written"
(the stored values are right) and crashes on the BVH build kernels.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

_LIBRARY = "liboclgrind-rt-icd.so"
_FOLDERS = (
    "/usr/lib/oclgrind",
    "/usr/lib/x86_64-linux-gnu/oclgrind",
    "/usr/local/lib/oclgrind",
    "/usr/lib64/oclgrind",
    "/usr/local/lib",
)
# API notices that are not ao4d's: device queries of properties newer than OpenCL 1.2 (pyopencl
# asks for them) and pyopencl's probe of a program attribute as a kernel name
_HARMLESS = (
    re.compile(r"Function: clGetDeviceInfo\s+Error:\s+CL_INVALID_VALUE\s+For argument 'param_name'"),
    re.compile(r"Function: clCreateKernel\s+Error:\s+CL_INVALID_KERNEL_NAME\s+Kernel '_source' not found"),
)


def oclgrind_library() -> Path | None:
    for folder in _FOLDERS:
        path = Path(folder) / _LIBRARY
        if path.is_file():
            return path
    return None


def kernel_names() -> set[str]:
    from ao4d._resources import data_dir

    text = "\n".join(p.read_text() for p in data_dir("kernels").glob("*.cl"))
    # attributes hold parentheses of their own (vec_type_hint(float4)); macros such as
    # CHUNK_KERNEL may stand between __kernel and void
    text = re.sub(r"__attribute__\s*\(\((?:[^()]|\([^()]*\))*\)\)", "", text)
    return set(re.findall(r"__kernel\s+(?:\w+\s+)*?void\s+(\w+)\s*\(", text))


def test_every_kernel_runs_clean_under_oclgrind(tmp_path):
    library = oclgrind_library()
    if library is None:
        pytest.skip(f"Oclgrind is not installed (no {_LIBRARY}; Debian: apt-get install oclgrind)")
    icd = tmp_path / "icd"
    icd.mkdir()
    (icd / "oclgrind.icd").write_text(f"{library}\n")
    log = tmp_path / "oclgrind.log"
    env = dict(os.environ)
    env.update(
        OCL_ICD_VENDORS=str(icd),
        AO4D_DEVICE="oclgrind",
        AO4D_PRELOAD_TBB="0",  # the simulator needs none of the Intel runtime's libraries
        OCLGRIND_CHECK_API="1",
        OCLGRIND_DATA_RACES="1",
        OCLGRIND_LOG=str(log),
    )
    script = Path(__file__).with_name("_oclgrind_check.py")
    run = subprocess.run(
        [sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=1800, cwd=tmp_path, check=False
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "device: Oclgrind" in run.stdout
    assert "BAD" not in run.stdout
    ran = set(run.stdout.split("kernels run:")[1].split())
    missing = kernel_names() - ran
    assert not missing, f"kernels not exercised under Oclgrind: {sorted(missing)}"
    reports = [b.strip() for b in (log.read_text() if log.exists() else "").split("\n\n") if b.strip()]
    problems = [b for b in reports if not any(p.search(b) for p in _HARMLESS)]
    assert not problems, "Oclgrind reported:\n\n" + "\n\n".join(problems[:10])
