"""Model files of an ingest: folders searched for them, and each file's content hash.

Files are hashed through :mod:`surfidx.io.files` (regular files only, never beyond the size a file
had when it was opened), so a FIFO or a file that grows while it is read cannot stall the run.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

from surfidx.errors import InputError
from surfidx.io.files import file_pieces

__all__ = ["discover", "hash_files"]


# ---------------------------------------------------------------------- discovery
def discover(paths, *, roots: bool = False):
    """The model files named by ``paths``, absolute (symbolic links kept), deduplicated, sorted.

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        Files (taken as given, whatever their suffix or type) and folders (searched recursively
        for every suffix in ``surfidx.io.SUPPORTED_SUFFIXES``, case-insensitively; hidden entries
        skipped). Entries that are not regular files are listed too: :func:`make_tasks` skips
        them with the reason.

    roots : bool
        Also return each file's root: the deepest folder of ``paths`` holding it (its own
        folder for a file named itself), which the stored source path is relative to.

    Returns
    -------
    list of pathlib.Path
        And with ``roots`` a dict file -> root folder (absolute).

    Raises
    ------
    InputError
        A path does not exist, ``paths`` is empty, or the folders given hold no supported file
        and no file was named (nothing to ingest).
    """
    from surfidx.io import SUPPORTED_SUFFIXES

    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    paths = list(paths)
    if not paths:
        raise InputError("give at least one model file or folder to ingest")
    found = set()
    root_of = {}
    empty_folders = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            before = len(found)
            for root, dirs, files in os.walk(p):
                dirs[:] = [d for d in dirs if not d.startswith(".")]
                for f in files:
                    if not f.startswith(".") and Path(f).suffix.lower() in SUPPORTED_SUFFIXES:
                        file = Path(os.path.abspath(Path(root, f)))
                        found.add(file)
                        top = Path(os.path.abspath(p))
                        if file not in root_of or len(top.parts) > len(root_of[file].parts):
                            root_of[file] = top
            if len(found) == before:
                empty_folders.append(p)
        elif p.exists():                            # a file, or a FIFO/device (skipped later)
            file = Path(os.path.abspath(p))
            found.add(file)
            root_of.setdefault(file, file.parent)
        else:
            raise InputError("no such file or folder", path=p)
    if not found:
        raise InputError("holds no model file (supported: " + ", ".join(SUPPORTED_SUFFIXES)
                         + ")", path=empty_folders[0])
    for folder in empty_folders:
        import warnings

        warnings.warn(f"{folder}: holds no model file (supported: "
                      + ", ".join(SUPPORTED_SUFFIXES) + ")", UserWarning, stacklevel=2)
    return (sorted(found), root_of) if roots else sorted(found)


def hash_files(path, *, texture=None) -> str:
    """SHA-256 hex of a model file's bytes and then its texture's (as
    ``surfidx.pipeline.content_hash``), reading regular files only and each no further than
    its size when opened.

    Raises
    ------
    surfidx.io.NotRegularFile
        ``path`` or ``texture`` is a FIFO, device, socket or directory (or a link to one).
    OSError
        A file cannot be opened or read.
    """
    h = hashlib.sha256()
    for p in (path, texture):
        if p is not None:
            for chunk in file_pieces(p, lambda fh, n: fh.read(n)):
                h.update(chunk)
    return h.hexdigest()
