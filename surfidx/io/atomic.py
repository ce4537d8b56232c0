"""Writing a file whole or not at all (:func:`write_atomic`)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import FileFormatError


def write_atomic(path, write, *, what: str = "") -> None:
    """Write a file whole or not at all: ``write(tmp)`` fills a temporary file in the target's
    folder, which then replaces ``path``; on an error the temporary file is removed.

    The temporary file is created exclusively under a fresh name (``.NAME.XXXXXXXX.part``), so
    nothing at a predictable name, a symlink in particular, is ever followed or overwritten;
    ``path`` itself is replaced, not written through (a symlink at ``path`` becomes the file).
    The file gets the permissions a newly created file has (``0o666`` less the umask).

    Parameters
    ----------
    path : str or os.PathLike
    write : callable
        ``write(tmp)`` writes the content to the :class:`pathlib.Path` ``tmp``.
    what : str
        What is written, for the error message.

    Raises
    ------
    FileFormatError
        Naming ``path`` (and ``what`` was being written) when the file cannot be written.
    """
    path = Path(path)
    tmp = None
    try:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix="." + path.name + ".",
                                    suffix=".part")
        tmp = Path(name)
        try:
            os.fchmod(fd, 0o666 & ~_umask())
        finally:
            os.close(fd)
        write(tmp)
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        raise FileFormatError(f"cannot write {what + ' ' if what else ''}({exc.strerror or exc})",
                              path=path) from exc
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
