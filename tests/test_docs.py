"""The documentation site (docs/) builds with Sphinx with warnings as errors: every page, the
command-line reference from the click commands, and the API reference from the docstrings (a
public name without a docstring, or a reference to nothing, fails the build)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from conftest import REPO

pytest.importorskip("sphinx")
pytest.importorskip("numpydoc")
pytest.importorskip("sphinx_click")
pytest.importorskip("myst_parser")


def build(tmp_path, *extra):
    """Build the site into ``tmp_path`` from scratch, nitpicky, warnings as errors."""
    out = tmp_path / "html"
    cmd = [sys.executable, "-m", "sphinx", "-b", "html", "-E", "-n", "-W", "--keep-going",
           "-q", "-d", str(tmp_path / "doctrees"), *extra, str(REPO / "docs"), str(out)]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path), out


def test_docs_build_without_warnings(tmp_path):
    proc, out = build(tmp_path)
    assert proc.returncode == 0, proc.stderr[-6000:]
    # the generated references are there: a command with its options, the API with its names
    cli = (out / "cli.html").read_text(encoding="utf-8")
    assert "surfidx-ingest" in cli and "--bits-per-surfel" in cli
    api = (out / "api" / "database.html").read_text(encoding="utf-8")
    assert 'id="surfidx.database.Database.query"' in api
    assert 'id="surfidx.database.Database.list_models"' in api    # inherited from the catalog
    assert (out / "benchmarks" / "index.html").exists()


def test_docs_fail_on_broken_reference_and_missing_docstring(tmp_path):
    """The checks that make the build strict: a page with a reference to nothing and a public
    name without a docstring each fail it."""
    src = tmp_path / "src"
    (src / "pkg").mkdir(parents=True)
    (src / "pkg" / "__init__.py").write_text('"""A package."""\n__all__ = ["f", "g"]\n\n\n'
                                             'def f():\n    """Documented."""\n\n\n'
                                             'def g():\n    pass\n')
    (src / "conf.py").write_text(
        "import sys\n"
        f"sys.path[:0] = [{str(src)!r}, {str(REPO / 'docs' / '_ext')!r}]\n"
        "extensions = ['sphinx.ext.autodoc', 'numpydoc', 'surfidx_api']\n"
        "nitpicky = True\n")
    (src / "index.rst").write_text("Test\n====\n\n.. public-api:: pkg\n\n"
                                   "See :func:`pkg.f` and :func:`pkg.nothing`.\n")
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-b", "html", "-E", "-n", "-q",
                           str(src), str(tmp_path / "out")], capture_output=True, text=True)
    assert "public name pkg.g has no docstring" in proc.stderr
    assert "pkg.nothing" in proc.stderr
    assert "pkg.f" not in proc.stderr.replace("pkg.nothing", "")
