"""Stage progress of the per-model work: the callback protocol, and the stderr display of the
CLI.

A *progress callback* is any callable ``progress(stage, done, total)``: ``stage`` is a name of
:data:`STAGES`, ``done`` of ``total`` steps of it are finished (``done == 0`` as it starts,
``done == total`` as it ends; the map reports its levels, ``("map", 2, 7)``). It is passed
explicitly, keyword-only, as ``progress=`` to :func:`surfidx.pipeline.process_model`,
:func:`surfidx.pipeline.describe_model`, :class:`surfidx.codec.Encoder` (and its ``encode``)
and :func:`surfidx.sphere.parameterize`; None reports nothing. Callbacks see the stage
boundaries only: they never change a result (streams and descriptors are the same with and
without one).

:class:`StageLog` is the CLI's callback: a one-line display on a terminal, and per-stage times.
"""

from __future__ import annotations

import time

__all__ = ["STAGES", "LABELS", "report", "StageLog", "stage_fraction"]

STAGES = ("read", "map", "figures", "resample", "transform", "code", "decode",
          "evaluate", "describe", "thumbnail", "write", "search", "render", "path")
"""The stage names a progress callback receives, in the order the pipeline runs them (the last
two are the ``render`` and ``geodesic`` commands' own)."""

LABELS = {"read": "reading", "map": "mapping", "figures": "map figures", "resample": "resampling", "transform": "transforming",
          "code": "coding", "decode": "decoding", "evaluate": "evaluating",
          "describe": "describing", "thumbnail": "drawing the thumbnail", "write": "writing",
          "search": "searching", "render": "rendering", "path": "finding the path"}
"""What the display calls each stage."""

#: Share of a whole ingest of one model each stage takes (rough CPU shares on the retrieval
#: models), for a progress bar that moves within a model (:func:`stage_fraction`).
_WEIGHTS = {"read": 0.04, "map": 0.53, "figures": 0.04, "resample": 0.06,
            "transform": 0.08, "code": 0.06, "decode": 0.04, "evaluate": 0.05,
            "describe": 0.06, "thumbnail": 0.04, "write": 0.0, "search": 0.0, "render": 0.0,
            "path": 0.0}


def report(progress, stage: str, done: int = 0, total: int = 1) -> None:
    """Call ``progress(stage, done, total)`` unless ``progress`` is None."""
    if progress is not None:
        progress(stage, int(done), int(total))


def stage_fraction(stage: str, done: int, total: int) -> float:
    """The share of one model's ingest finished at the event ``(stage, done, total)``: the
    weights of the stages before ``stage`` and the done part of its own, in [0, 1]."""
    if stage not in _WEIGHTS:
        return 0.0
    before = sum(_WEIGHTS[s] for s in STAGES[:STAGES.index(stage)])
    part = min(max(done / total, 0.0), 1.0) if total > 0 else 0.0
    return min(before + _WEIGHTS[stage] * part, 1.0)


class StageLog:
    """A progress callback that shows the running stage on one line of a terminal stream and
    records the wall and CPU time of each stage.

    A stage runs from its first event to the first event of another stage (or :meth:`close`).

    Parameters
    ----------
    stream : text stream
        Where the display and the times go (the CLI: stderr).
    live : bool
        Rewrite one line with the running stage (``"\\r"``; for a terminal).
    verbose : bool
        On :meth:`close`, print one line per stage with its times.

    Attributes
    ----------
    seconds : dict of str -> (float, float)
        Wall and CPU seconds of each stage that ran (a stage that runs twice adds up).
    """

    def __init__(self, stream, *, live: bool = False, verbose: bool = False):
        self.stream = stream
        self.live = bool(live)
        self.verbose = bool(verbose)
        self.seconds = {}
        self._stage = None
        self._t0 = (0.0, 0.0)
        self._shown = 0
        self._text = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage != self._stage:
            self._end()
            self._stage = stage
            self._t0 = (time.perf_counter(), time.process_time())
        if self.live:
            label = LABELS.get(stage, stage)
            if stage == "map" and total > 1:
                label += f" (level {done}/{total})"
            self._show(label + "\u2026")

    def _show(self, text: str) -> None:
        if text == self._text:
            return
        self._text = text
        pad = max(self._shown - len(text), 0)
        self.stream.write("\r" + text + " " * pad + ("\r" + text if pad else ""))
        self.stream.flush()
        self._shown = len(text)

    def _end(self) -> None:
        if self._stage is None:
            return
        wall = time.perf_counter() - self._t0[0]
        cpu = time.process_time() - self._t0[1]
        w, c = self.seconds.get(self._stage, (0.0, 0.0))
        self.seconds[self._stage] = (w + wall, c + cpu)
        self._stage = None

    def close(self) -> None:
        """End the running stage, clear the display line, and (``verbose``) print the times."""
        self._end()
        if self.live and self._shown:
            self.stream.write("\r" + " " * self._shown + "\r")
            self.stream.flush()
            self._shown = 0
            self._text = None
        if self.verbose and self.seconds:
            for stage, (wall, cpu) in self.seconds.items():
                self.stream.write(f"{stage:10s} {wall:8.2f} s wall {cpu:8.2f} s CPU\n")
            total = [sum(v[i] for v in self.seconds.values()) for i in (0, 1)]
            self.stream.write(f"{'total':10s} {total[0]:8.2f} s wall {total[1]:8.2f} s CPU\n")
            self.stream.flush()
