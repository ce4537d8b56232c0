"""One floating-point profile on every x86-64 machine, so that a file gives the same bytes anywhere.

numpy and OpenBLAS choose their SIMD kernels for the CPU when they are loaded: on an AVX-512
machine numpy's ``exp``, ``log``, reductions and sorts and OpenBLAS's products run AVX-512 code
whose results differ in the last bits from the AVX2 code of other machines, and the sphere
stage's iterations grow such bits into a different map. OpenBLAS also sums a long dot product in
an order that depends on its thread count. The portable profile asks both libraries for the
kernels of x86-64-v3 (AVX2 and FMA, which every x86-64 server of the last ten years has) and
OpenBLAS for one thread: ``NPY_DISABLE_CPU_FEATURES`` names numpy's AVX-512 targets,
``OPENBLAS_CORETYPE`` is ``Haswell`` (only where ``/proc/cpuinfo`` shows AVX2 and FMA: forcing it
elsewhere would stop the process), ``OPENBLAS_NUM_THREADS`` is 1. A variable the user set is kept.

These variables act only before numpy loads, so the profile is a property of a process, chosen
by whoever starts it. ``import surfidx`` changes nothing in the host process. The ``surfidx``
command (:func:`use_portable_profile` before anything else), the worker processes of a bulk
ingestion (:func:`portable_context`) and the Dask workers surfidx launches compute in the
profile; a library user who imported numpy first gets correct results in the machine's own
profile, and every stored model records the profile it was made in (:func:`provenance`), so a
record made elsewhere is recognisable.
"""

from __future__ import annotations

import multiprocessing.context as _mpc
import os
import platform
import sys
import threading

__all__ = ["PROFILE", "numerics_profile", "portable_environment", "use_portable_profile",
           "portable_context", "environment", "provenance"]

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
_LOCK = threading.Lock()   # os.environ is changed around a child process start only


def is_x86_64() -> bool:
    """Whether this machine is x86-64 (``platform.machine()``).

    Returns
    -------
    bool
    """
    return platform.machine().lower() in ("x86_64", "amd64")


def _numpy_names_levels() -> bool:
    """Whether the installed numpy names its targets by level (numpy 2.4 and later).

    The version is read without importing numpy (this runs before numpy loads) and without
    ``importlib.metadata`` (whose imports cost more than the rest of a command's start-up):
    from ``numpy/version.py`` beside numpy's ``__init__``, else from the package metadata.
    """
    import importlib.util
    import re

    text = None
    try:
        spec = importlib.util.find_spec("numpy")
        if spec is not None and spec.origin:
            with open(os.path.join(os.path.dirname(spec.origin), "version.py"),
                      encoding="utf-8") as f:
                text = f.read()
    except (OSError, ImportError, ValueError):
        text = None
    found = re.search(r'^version\s*=\s*["\'](\d+)\.(\d+)', text or "", re.MULTILINE)
    if found:
        return (int(found.group(1)), int(found.group(2))) >= (2, 4)
    from importlib.metadata import PackageNotFoundError, version

    try:
        major, minor = (int(p) for p in version("numpy").split(".")[:2])
    except (PackageNotFoundError, ValueError):
        return True
    return (major, minor) >= (2, 4)


def cpu_flags() -> frozenset[str] | None:
    """The CPU's feature flags from ``/proc/cpuinfo`` (Linux), or None where it cannot be read."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:
        return None
    return None


def portable_environment() -> dict[str, str]:
    """The environment variables that put a new process in the portable profile.

    Returns
    -------
    dict of str -> str
        The variables this machine needs (none of the user's own is overridden: a variable set
        in ``os.environ`` is left out). Reading it changes nothing.
    """
    env = {"OPENBLAS_NUM_THREADS": _BLAS_THREADS}
    if is_x86_64():
        env["NPY_DISABLE_CPU_FEATURES"] = " ".join(_AVX512_TARGETS[_numpy_names_levels()])
        flags = cpu_flags()
        if flags is not None and {"avx2", "fma"} <= flags:
            env["OPENBLAS_CORETYPE"] = _BLAS_CORE
    return {k: v for k, v in env.items() if k not in os.environ}


def use_portable_profile() -> None:
    """Put this process in the portable profile: for the code that owns the process.

    The ``surfidx`` command runs it first; a script or test harness that wants the bytes the
    command makes runs it before importing numpy. It writes :func:`portable_environment` into
    ``os.environ`` (inherited by the processes this one starts). When numpy was loaded already,
    its OpenBLAS is limited to one thread now (a count the user set is kept), and when it runs
    other kernels a RuntimeWarning says so and how to avoid it. Library code never calls it.
    """
    users_threads = "OPENBLAS_NUM_THREADS" in os.environ
    env = portable_environment()
    os.environ.update(env)
    if "numpy" not in sys.modules:
        return
    if not users_threads:
        _limit_loaded_blas()
    profile = numerics_profile()
    if profile != PROFILE:
        import warnings

        spelled = " ".join(f"{k}='{v}'" for k, v in env.items())
        warnings.warn(
            f"numpy was imported before the portable profile was set and computes in profile "
            f"{profile!r}: streams and descriptors made in this process may differ from other "
            f"machines' (call use_portable_profile() before importing numpy, or start Python "
            f"with {spelled})", RuntimeWarning, stacklevel=2)


def portable_context():
    """A multiprocessing context whose processes are spawned in the portable profile.

    Each process starts with :func:`portable_environment` added to the environment it inherits;
    this process's own ``os.environ`` is restored as soon as the child has started (a forked
    child would inherit this process's loaded numpy instead).

    Returns
    -------
    multiprocessing.context.SpawnContext
    """
    return _PortableSpawnContext()


class _PortableSpawnProcess(_mpc.SpawnProcess):
    @staticmethod
    def _Popen(process_obj):
        with environment(portable_environment()):
            return _mpc.SpawnProcess._Popen(process_obj)


class _PortableSpawnContext(_mpc.SpawnContext):
    Process = _PortableSpawnProcess


class environment:
    """``os.environ`` with ``env`` added inside the block and as it was after (a lock keeps two
    blocks apart): for starting a child process in the portable profile.

    Parameters
    ----------
    env : dict of str -> str
    """

    def __init__(self, env):
        self.env, self.saved = env, {}

    def __enter__(self):
        _LOCK.acquire()
        self.saved = {k: os.environ.get(k) for k in self.env}
        os.environ.update(self.env)
        return self

    def __exit__(self, *exc):
        try:
            for k, v in self.saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
        finally:
            _LOCK.release()
        return False


def provenance() -> dict:
    """What made a record: surfidx's and its numerics' versions and the profile of this process.

    Returns
    -------
    dict
        ``surfidx``, ``numpy``, ``scipy``, ``numba`` versions and ``numerics_profile``
        (:func:`numerics_profile`): stored with every model, so that a record made in another
        profile or by another release is recognisable.
    """
    from importlib.metadata import PackageNotFoundError, version

    from . import __version__

    out = {"surfidx": __version__}
    for name in ("numpy", "scipy", "numba"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:  # pragma: no cover - dependencies
            out[name] = None
    out["numerics_profile"] = numerics_profile()
    return out


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
    if not is_x86_64():
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
