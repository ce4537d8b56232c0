"""The numerics profile: the same kernels, so the same bytes, on every x86-64 machine."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

import surfidx
from surfidx._numerics import PROFILE, _cpu_flags, _x86_64

x86_avx2 = pytest.mark.skipif(
    not _x86_64() or not {"avx2", "fma"} <= (_cpu_flags() or frozenset()),
    reason="the portable profile is x86-64-v3 (AVX2 and FMA)")


def _python(code: str, **env: str) -> subprocess.CompletedProcess:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS",
                          "OMP_NUM_THREADS")}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**clean, **env}, timeout=120)


@x86_avx2
def test_the_test_process_computes_in_the_portable_profile():
    assert surfidx.numerics_profile() == PROFILE == "x86-64-v3"


@x86_avx2
def test_import_surfidx_first_sets_the_profile_for_numpy_and_openblas():
    out = _python("import os, surfidx, scipy.linalg; print(surfidx.numerics_profile()); "
                  "print(os.environ['OPENBLAS_CORETYPE'])")
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [PROFILE, "Haswell"]


@x86_avx2
def test_a_users_own_blas_kernels_are_kept_and_named():
    out = _python("import surfidx; print(surfidx.numerics_profile())",
                  OPENBLAS_CORETYPE="Sandybridge")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "native (OpenBLAS Sandybridge kernels)"


@x86_avx2
def test_numpy_loaded_first_with_other_kernels_is_warned_about():
    """Only where numpy's own choice differs (an AVX-512 machine, or OpenBLAS picking kernels
    other than Haswell's): elsewhere numpy loaded first computes as the profile does."""
    native = _python("import numpy, surfidx; print(surfidx.numerics_profile())")
    assert native.returncode == 0, native.stderr
    profile = native.stdout.strip()
    if profile == PROFILE:
        assert "RuntimeWarning" not in native.stderr
    else:
        assert profile.startswith("native (")
        assert "numpy was imported before surfidx" in native.stderr
        assert "OPENBLAS_CORETYPE=Haswell" in native.stderr


@x86_avx2
def test_one_blas_thread_unless_the_user_asks_for_more():
    """A threaded dot product adds its parts in an order that depends on the thread count, and
    the map changed with it: surfidx asks OpenBLAS for one thread (numpy's and scipy's); a
    user's own count is kept and named."""
    out = _python("import os, surfidx, scipy.linalg; from threadpoolctl import threadpool_info; "
                  "print(surfidx.numerics_profile()); print(os.environ['OPENBLAS_NUM_THREADS']); "
                  "print(sorted({lib['num_threads'] for lib in threadpool_info() "
                  "if lib['internal_api'] == 'openblas'}))")
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [PROFILE, "1", "[1]"]
    two = _python("import surfidx, scipy.linalg; print(surfidx.numerics_profile())",
                  OPENBLAS_NUM_THREADS="2")
    assert two.returncode == 0, two.stderr
    assert two.stdout.strip() == "native (OpenBLAS 2 threads)"


def test_numpy_loaded_first_gets_one_blas_thread_at_import():
    """Threads, unlike kernels, can still be changed once numpy is loaded: ``import surfidx``
    limits them (not a count the user set)."""
    code = ("import numpy, surfidx; from threadpoolctl import threadpool_info; "
            "print(sorted({lib['num_threads'] for lib in threadpool_info() "
            "if lib['internal_api'] == 'openblas'}))")
    out = _python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[-1] == "[1]"
    if (os.cpu_count() or 1) > 1:
        kept = _python(code, OPENBLAS_NUM_THREADS="2")
        assert kept.returncode == 0, kept.stderr
        assert kept.stdout.split()[-1] == "[2]"
