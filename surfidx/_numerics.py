"""One floating-point profile on every x86-64 machine, so that a file gives the same bytes anywhere.

numpy and OpenBLAS choose their SIMD kernels for the CPU when they are loaded: on an AVX-512
machine numpy's ``exp``, ``log``, reductions and sorts and OpenBLAS's products run AVX-512 code
whose results differ in the last bits from the AVX2 code of other machines. The sphere stage's
iterations grow such bits into a different map, so the same file gave different streams on two
machines (the blob and spot streams of the tests). Before numpy is loaded, surfidx asks both
libraries for the kernels of x86-64-v3 (AVX2 and FMA), which every x86-64 server of the last ten
years has: ``NPY_DISABLE_CPU_FEATURES`` names numpy's AVX-512 targets and ``OPENBLAS_CORETYPE``
is ``Haswell`` (set only where ``/proc/cpuinfo`` shows AVX2 and FMA: forcing it elsewhere would
stop the process). OpenBLAS also splits a long dot product among its threads, one per core by
default, and adds the parts in an order that depends on their number: the same map came out
different with one BLAS thread and with two. So surfidx asks for one (``OPENBLAS_NUM_THREADS=1``;
the work is sparse solves and small dense products, and a worker process per core is what runs
in parallel). A variable the user set is kept. When numpy was imported before surfidx, its
OpenBLAS threads are limited at import (threadpoolctl) but its kernels cannot be changed any
more; :func:`numerics_profile` then says whether the process still computes as every other one
does.
"""

from __future__ import annotations

import os
import platform
import sys

__all__ = ["PROFILE", "numerics_profile", "use_portable_profile"]

PROFILE = "x86-64-v3"
"""The name of the profile that gives the same bytes on every x86-64 machine."""

# numpy's dispatch targets above x86-64-v3: named by level from numpy 2.4, by feature before
_AVX512_TARGETS = {
    True: ("X86_V4", "AVX512_ICL", "AVX512_SPR"),
    False: ("AVX512F", "AVX512CD", "AVX512_KNL", "AVX512_KNM", "AVX512_SKX", "AVX512_CLX",
            "AVX512_CNL", "AVX512_ICL", "AVX512_SPR"),
}
_BLAS_CORE = "Haswell"
_BLAS_THREADS = "1"   # a threaded dot product sums in a thread-count-dependent order


def _x86_64() -> bool:
    return platform.machine().lower() in ("x86_64", "amd64")


def _numpy_names_levels() -> bool:
    """Whether the installed numpy names its targets by level (numpy 2.4 and later)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        major, minor = (int(p) for p in version("numpy").split(".")[:2])
    except (PackageNotFoundError, ValueError):
        return True
    return (major, minor) >= (2, 4)


def _cpu_flags() -> frozenset[str] | None:
    """The CPU's feature flags from ``/proc/cpuinfo`` (Linux), or None where it cannot be read."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        return None
    return None


def use_portable_profile() -> None:
    """Ask numpy and OpenBLAS for the x86-64-v3 kernels and OpenBLAS for one thread, before
    they load.

    Runs first in ``import surfidx``. The environment variables it sets are inherited by the
    worker processes of a bulk ingestion, so they compute alike too. When numpy was loaded
    already, its OpenBLAS is limited to one thread now (threads, unlike kernels, can still be
    changed; a count the user set is kept), and when it runs other kernels a RuntimeWarning says
    so and how to avoid it.
    """
    users_threads = "OPENBLAS_NUM_THREADS" in os.environ
    os.environ.setdefault("OPENBLAS_NUM_THREADS", _BLAS_THREADS)
    if "numpy" in sys.modules and not users_threads:
        _limit_loaded_blas()
    if not _x86_64():
        return
    os.environ.setdefault("NPY_DISABLE_CPU_FEATURES",
                          " ".join(_AVX512_TARGETS[_numpy_names_levels()]))
    flags = _cpu_flags()
    if flags is not None and {"avx2", "fma"} <= flags:
        os.environ.setdefault("OPENBLAS_CORETYPE", _BLAS_CORE)
    if "numpy" in sys.modules:
        profile = numerics_profile()
        if profile != PROFILE:
            import warnings

            warnings.warn(
                f"numpy was imported before surfidx and computes in profile {profile!r}: "
                f"streams and descriptors made in this process may differ from other "
                f"machines' (import surfidx before numpy, or start Python with "
                f"NPY_DISABLE_CPU_FEATURES='{os.environ['NPY_DISABLE_CPU_FEATURES']}' "
                f"OPENBLAS_CORETYPE={_BLAS_CORE} OPENBLAS_NUM_THREADS={_BLAS_THREADS})",
                RuntimeWarning, stacklevel=3)


def _limit_loaded_blas() -> None:
    """One thread for the OpenBLAS libraries loaded already (numpy imported before surfidx)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - scikit-learn brings threadpoolctl
        return
    threadpool_limits(limits=int(_BLAS_THREADS), user_api="blas")


def _blas_libraries() -> list[tuple[str, int]]:
    """Kernel family and thread count of each OpenBLAS library loaded in this process."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:  # pragma: no cover - scikit-learn brings threadpoolctl
        return [(os.environ.get("OPENBLAS_CORETYPE", "unknown"),
                 int(os.environ.get("OPENBLAS_NUM_THREADS", "0") or 0))]
    # an OpenMP build (faiss's own, which the ANN index runs on one thread) follows
    # OMP_NUM_THREADS, not OPENBLAS_NUM_THREADS: its threads are not counted
    return [(str(lib.get("architecture")),
             0 if lib.get("threading_layer") == "openmp" else int(lib.get("num_threads") or 0))
            for lib in threadpool_info() if lib.get("internal_api") == "openblas"]


def numerics_profile() -> str:
    """The floating-point profile this process computes in.

    Returns
    -------
    str
        :data:`PROFILE` on x86-64 when numpy runs no AVX-512 kernel and every loaded OpenBLAS
        runs its Haswell kernels; otherwise ``"native (...)"`` naming what differs, e.g.
        ``"native (numpy AVX-512 kernels, OpenBLAS SkylakeX kernels)"`` when numpy was imported
        before surfidx on an AVX-512 machine. Streams and descriptors are the same bytes on
        every machine that computes in one profile.
    """
    if not _x86_64():
        return f"native ({platform.machine() or 'unknown CPU'})"
    import numpy  # noqa: F401  (loads the feature table and numpy's OpenBLAS)

    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:  # numpy 1.26
        from numpy.core._multiarray_umath import __cpu_features__ as features
    differs = []
    if any(features.get(name) for name in _AVX512_TARGETS[_numpy_names_levels()]):
        differs.append("numpy AVX-512 kernels")
    libraries = _blas_libraries()
    cores = sorted({c for c, _ in libraries if c.lower() != _BLAS_CORE.lower()})
    if cores:
        differs.append(f"OpenBLAS {'/'.join(cores)} kernels")
    threads = sorted({t for _, t in libraries if t > int(_BLAS_THREADS)})
    if threads:
        differs.append(f"OpenBLAS {'/'.join(map(str, threads))} threads")
    return PROFILE if not differs else f"native ({', '.join(differs)})"
