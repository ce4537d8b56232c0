"""Benchmark pages for the documentation: a script's ``--markdown`` writes its tables to
``docs/benchmarks/<name>.md``, under a header saying when, on what machine and at which commit
they were measured, and with which command.

A script makes one :class:`Report` and sends its output through it: :meth:`Report.table` prints
a table as aligned text and keeps it as a Markdown table, :meth:`Report.text` a paragraph,
:meth:`Report.print` lines kept verbatim (a preformatted block on the page). :meth:`Report.finish`
writes the page when ``--markdown`` was given (:func:`add_markdown_option`). Without it the
script prints what it printed before and writes nothing.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "benchmarks"

__all__ = ["Report", "add_markdown_option", "machine", "commit", "header", "markdown_table",
           "text_table"]


def add_markdown_option(parser, name: str) -> None:
    """Add ``--markdown [FILE]`` to an argparse parser: write the page (default
    ``docs/benchmarks/<name>.md``)."""
    parser.add_argument("--markdown", nargs="?", type=Path, const=DOCS / f"{name}.md",
                        default=None, metavar="FILE",
                        help=f"also write the tables as a documentation page (default "
                             f"docs/benchmarks/{name}.md)")


def machine() -> str:
    """The CPU model, the cores this process may use and the memory, e.g.
    ``Intel(R) Xeon(R) Processor, 2 cores, 24 GiB``."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    memory = ""
    try:
        pages = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        memory = f", {pages / 2 ** 30:.0f} GiB"
    except (ValueError, OSError, AttributeError):
        pass
    return f"{model}, {cores} cores{memory}"


def commit() -> str:
    """The repository's commit (short hash), with ``+ changes`` when tracked files outside
    ``docs/`` differ from it."""
    def git(*args):
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                               timeout=30).stdout.strip()
    try:
        head = git("rev-parse", "--short=12", "HEAD")
        # the pages themselves (docs/) do not count: a run of several scripts writes them
        dirty = git("status", "--porcelain", "--untracked-files=no", "--", ".", ":!docs")
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    if not head:
        return "unknown"
    return f"{head} + changes" if dirty else head


def header(title: str, command: str, *, note: str = "") -> str:
    """The page's title and the measurement's circumstances, as Markdown."""
    import numpy as np

    import surfidx

    when = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"# {title}", "",
             f"Measured {when} on {machine()}, commit `{commit()}` (surfidx "
             f"{surfidx.__version__}, Python {platform.python_version()}, numpy "
             f"{np.__version__}, numerics profile `{surfidx.numerics_profile()}`).", "",
             "```bash", command, "```", ""]
    if note:
        lines += [note, ""]
    return "\n".join(lines)


def _cell(value) -> str:
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(headers, rows) -> str:
    """A Markdown table (numbers right-aligned when a column holds only numbers)."""
    rows = [[_cell(c) for c in r] for r in rows]
    align = []
    for j in range(len(headers)):
        col = [r[j] for r in rows if j < len(r) and r[j] not in ("", "-")]
        numeric = bool(col) and all(_numeric(c) for c in col)
        align.append("---:" if numeric else "---")
    out = ["| " + " | ".join(_cell(h) for h in headers) + " |", "|" + "|".join(align) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def _numeric(text: str) -> bool:
    try:
        float(text.replace(",", "").replace("%", "").replace("+", ""))
        return True
    except ValueError:
        return False


def text_table(headers, rows) -> str:
    """The table as aligned plain text (what the script prints)."""
    rows = [[str(c) for c in r] for r in rows]
    widths = [max([len(str(h))] + [len(r[j]) for r in rows if j < len(r)])
              for j, h in enumerate(headers)]
    def line(cells):
        return "  ".join(c.rjust(w) if _numeric(c) else c.ljust(w)
                         for c, w in zip(cells, widths)).rstrip()
    return "\n".join([line([str(h) for h in headers]), line(["-" * w for w in widths]),
                      *map(line, rows)])


class Report:
    """What a benchmark prints, kept for its documentation page.

    Parameters
    ----------
    name : str
        The page's file stem (``docs/benchmarks/<name>.md``), usually the script's.
    title : str
        The page's title.
    output : pathlib.Path or None
        Where to write the page (the ``--markdown`` option's value); None: print only.
    note : str
        A paragraph under the header: what the tables show, on which subset.
    """

    def __init__(self, name: str, title: str, output=None, *, note: str = ""):
        self.name, self.title, self.output, self.note = name, title, output, note
        self.parts: list[str] = []
        self._kind: str | None = None         # the open block: "text" (verbatim) or "markdown"
        self._lines: list[str] = []

    def _close(self):
        if self._kind == "text":
            self.parts.append("```text\n" + "\n".join(self._lines) + "\n```")
        elif self._kind == "markdown":
            self.parts.append("\n".join(self._lines))
        self._kind, self._lines = None, []

    def _add(self, kind: str, text: str) -> None:
        if self._kind != kind:
            self._close()
            self._kind = kind
        self._lines.extend(text.split("\n"))

    def heading(self, text: str) -> None:
        """A section heading (printed as a line)."""
        print(f"\n{text}")
        self._close()
        self.parts.append(f"## {text}")

    def text(self, text: str) -> None:
        """A paragraph (printed as it is)."""
        print(text)
        self._close()
        self.parts.append(text)

    def table(self, headers, rows, *, title: str | None = None) -> None:
        """A table: printed aligned, kept as a Markdown table."""
        rows = [list(r) for r in rows]
        if title:
            print(f"\n{title}")
        print(text_table(headers, rows))
        self._close()
        if title:
            self.parts.append(f"**{title}**")
        self.parts.append(markdown_table(headers, rows))

    def print(self, *args, sep: str = " ", flush: bool = False) -> None:
        """Print a line and keep it verbatim (consecutive lines form one block)."""
        line = sep.join(str(a) for a in args)
        print(line, flush=flush)
        self._add("text", line.strip("\n"))

    def markdown(self, *args, sep: str = " ", flush: bool = False) -> None:
        """Print a line that is already Markdown (a table row: ``a | b | c``) and keep it as
        it is (consecutive lines form one block, so a table's rows stay together)."""
        line = sep.join(str(a) for a in args)
        print(line, flush=flush)
        if not line.strip():
            self._close()
            return
        self._add("markdown", line.strip("\n"))

    def finish(self, argv=None) -> Path | None:
        """Write the page when ``output`` is set; returns its path."""
        self._close()
        if self.output is None:
            return None
        argv = sys.argv if argv is None else argv
        script = Path(argv[0])
        try:
            script = script.resolve().relative_to(ROOT)
        except ValueError:
            pass
        command = shlex.join(["python", str(script), *argv[1:]])
        page = header(self.title, command, note=self.note) + "\n" \
            + "\n\n".join(self.parts) + "\n"
        path = Path(self.output)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(page, encoding="utf-8")
        print(f"\n{path}: written", file=sys.stderr)
        return path
