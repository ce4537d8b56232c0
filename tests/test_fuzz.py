"""Bounded fuzzing (issue 28): seeded mutations of valid streams and model files, a fixed count
of each, run in-process by the generators of ``benchmarks/fuzz.py`` (which runs them at scale in
worker processes with memory limits). Every case must give finite output or a library error,
within a generous per-case time limit."""

import importlib.util
import signal
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CASE_SECONDS = 30.0  # generous: the machine is shared; a hang used to take minutes


def _load_fuzz():
    spec = importlib.util.spec_from_file_location("surfidx_fuzz", REPO / "benchmarks" / "fuzz.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


fuzz = _load_fuzz()


class _Overtime(Exception):
    pass


def _run(kind, payload, workdir):
    """Run one case with an alarm that interrupts a Python-level endless loop."""
    def alarm(signum, frame):
        raise _Overtime

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, CASE_SECONDS)
    t0 = time.perf_counter()
    try:
        outcome, detail = fuzz.run_case(kind, payload, workdir)
    except _Overtime:
        outcome, detail = "hang", f"over {CASE_SECONDS:g} s"
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    elapsed = time.perf_counter() - t0
    if outcome in ("ok", "clean error") and elapsed > CASE_SECONDS:
        outcome, detail = "hang", f"{elapsed:.1f} s"
    return outcome, detail


def _check(cases, workdir):
    seen, bad = {}, []
    for i, (kind, payload) in enumerate(cases):
        outcome, detail = _run(kind, payload, workdir)
        seen[outcome] = seen.get(outcome, 0) + 1
        if outcome not in ("ok", "clean error"):
            bad.append(f"case {i} ({kind}): {outcome}: {detail}")
    assert not bad, "\n".join(bad)
    return seen


@pytest.fixture(scope="module")
def stream_seeds():
    return fuzz.stream_seeds()


def test_seeds_are_valid(stream_seeds, tmp_path):
    for data in stream_seeds:
        assert fuzz.run_case("stream", data, tmp_path) == ("ok", "")
    for entry in fuzz.file_seeds():
        assert fuzz.run_case("PLY", entry, tmp_path) == ("ok", "")


def test_mutated_streams(stream_seeds, tmp_path):
    seen = _check(fuzz.stream_cases(stream_seeds, 300, seed=1), tmp_path)
    assert seen.get("ok", 0) > 30 and seen.get("clean error", 0) > 30  # both paths exercised


@pytest.mark.parametrize("kind", ["PLY", "OBJ/MTL", "OFF"])
def test_mutated_files(tmp_path, kind):
    seeds = [s for s in fuzz.file_seeds() if fuzz.file_kind(s[0]) == kind]
    seen = _check(fuzz.file_cases(seeds, 80, seed=2), tmp_path)
    assert seen.get("ok", 0) > 5 and seen.get("clean error", 0) > 5


def test_reseal_recomputes_lengths_and_checksums(stream_seeds):
    from surfidx.codec.container import unpack

    for data in stream_seeds:
        assert fuzz._reseal(data) == data
        unpack(fuzz._reseal(data[:-3]))  # a cut stream, resealed, is a valid container again
