"""The numerics profile: the same kernels, so the same bytes, on every x86-64 machine."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

import surfidx
import surfidx.numerics
from surfidx.numerics import PROFILE, cpu_flags, is_x86_64

x86_avx2 = pytest.mark.skipif(
    not is_x86_64() or not {"avx2", "fma"} <= (cpu_flags() or frozenset()),
    reason="the portable profile is x86-64-v3 (AVX2 and FMA)")


def _python(code: str, **env: str) -> subprocess.CompletedProcess:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS",
                          "OMP_NUM_THREADS")}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**clean, **env}, timeout=120)


_PORTABLE = "from surfidx.numerics import use_portable_profile; use_portable_profile(); "


@x86_avx2
def test_the_test_process_computes_in_the_portable_profile():
    assert surfidx.numerics_profile() == PROFILE == "x86-64-v3"


def test_import_surfidx_changes_nothing_in_the_host():
    """No environment variable, no thread limit, no output: numpy imported first (every
    notebook) keeps its own kernels and threads, silently."""
    code = ("import os, numpy; before = dict(os.environ); "
            "from threadpoolctl import threadpool_info; "
            "threads = lambda: {l['filepath']: l['num_threads'] for l in threadpool_info()}; "
            "t = threads(); import surfidx, surfidx.io, surfidx.db, surfidx.codec, surfidx.sphere; "
            "surfidx.SurfelSet; surfidx.Database; surfidx.encode; now = threads(); "
            "print(dict(os.environ) == before, all(now[k] == v for k, v in t.items()))")
    out = _python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "True"] and out.stderr == ""


@x86_avx2
def test_the_portable_profile_set_first_gives_x86_64_v3():
    out = _python(_PORTABLE + "import os, scipy.linalg, surfidx; print(surfidx.numerics_profile()); "
                  "print(os.environ['OPENBLAS_CORETYPE'])")
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [PROFILE, "Haswell"]


@x86_avx2
def test_the_command_computes_in_the_portable_profile():
    """``surfidx`` (:func:`surfidx.cli.main`) sets the profile before numpy loads."""
    code = ("import sys; from surfidx.cli import main; sys.argv = ['surfidx', '--version']; "
            "import atexit, os; atexit.register(lambda: print(os.environ['OPENBLAS_NUM_THREADS'], "
            "__import__('surfidx').numerics_profile())); main()")
    out = _python(code)
    assert out.stdout.split()[-2:] == ["1", PROFILE], out.stderr


@x86_avx2
def test_a_users_own_blas_kernels_are_kept_and_named():
    out = _python(_PORTABLE + "import surfidx; print(surfidx.numerics_profile())",
                  OPENBLAS_CORETYPE="Sandybridge")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "native (OpenBLAS Sandybridge kernels)"


@x86_avx2
def test_the_profile_set_after_numpy_with_other_kernels_is_warned_about():
    """Only where numpy's own choice differs (an AVX-512 machine, or OpenBLAS picking kernels
    other than Haswell's): elsewhere numpy loaded first computes as the profile does."""
    native = _python("import numpy, surfidx; " + _PORTABLE + "print(surfidx.numerics_profile())")
    assert native.returncode == 0, native.stderr
    profile = native.stdout.strip()
    if profile == PROFILE:
        assert "RuntimeWarning" not in native.stderr
    else:
        assert profile.startswith("native (")
        assert "numpy was imported before the portable profile was set" in native.stderr
        assert "OPENBLAS_CORETYPE='Haswell'" in native.stderr


@x86_avx2
def test_one_blas_thread_unless_the_user_asks_for_more():
    """A threaded dot product adds its parts in an order that depends on the thread count, and
    the map changed with it: the profile asks OpenBLAS for one thread (numpy's and scipy's); a
    user's own count is kept and named."""
    out = _python(_PORTABLE + "import os, surfidx, scipy.linalg; "
                  "from threadpoolctl import threadpool_info; "
                  "print(surfidx.numerics_profile()); print(os.environ['OPENBLAS_NUM_THREADS']); "
                  "print(sorted({lib['num_threads'] for lib in threadpool_info() "
                  "if lib['internal_api'] == 'openblas'}))")
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [PROFILE, "1", "[1]"]
    two = _python(_PORTABLE + "import surfidx, scipy.linalg; print(surfidx.numerics_profile())",
                  OPENBLAS_NUM_THREADS="2")
    assert two.returncode == 0, two.stderr
    assert two.stdout.strip() == "native (OpenBLAS 2 threads)"


@x86_avx2
def test_workers_started_from_a_native_process_compute_in_the_profile():
    """A library user who imported numpy first: the ingest workers surfidx starts are spawned
    in the portable profile, and this process's environment is as it was."""
    code = ("import os, numpy, surfidx, concurrent.futures as cf; before = dict(os.environ); "
            "from surfidx.numerics import portable_context, numerics_profile; "
            "pool = cf.ProcessPoolExecutor(1, mp_context=portable_context()); "
            "print(pool.submit(numerics_profile).result()); pool.shutdown(); "
            "print(dict(os.environ) == before)")
    out = _python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [PROFILE, "True"]


def test_provenance_names_versions_and_profile():
    record = surfidx.numerics.provenance()
    assert record["surfidx"] == surfidx.__version__
    assert set(record) == {"surfidx", "numpy", "scipy", "numba", "numerics_profile"}
    assert record["numerics_profile"] == surfidx.numerics_profile()
