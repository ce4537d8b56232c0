"""Exception hierarchy of surfidx.

Every error the library raises on purpose derives from :class:`SurfidxError`, so the CLI can map
them to one clear line and a non-zero exit (``click.ClickException``) while genuine bugs still
surface as tracebacks in tests.
"""

from __future__ import annotations

__all__ = [
    "SurfidxError",
    "InputError",
    "FileFormatError",
    "TopologyError",
    "BitstreamError",
    "DatabaseError",
]


class SurfidxError(Exception):
    """Base class of every error surfidx raises deliberately.

    Parameters
    ----------
    message : str
        What is wrong and, where possible, how to fix it.
    path : str or os.PathLike, optional
        The file the error concerns; it is prefixed to the message.
    """

    def __init__(self, message: str, *, path=None):
        self.path = None if path is None else str(path)
        self.reason = message
        super().__init__(f"{self.path}: {message}" if self.path else message)


class InputError(SurfidxError, ValueError):
    """An argument or data value is invalid (NaN, wrong shape, out of range, too few surfels)."""


class FileFormatError(SurfidxError, ValueError):
    """A file cannot be read: unknown format, truncated, corrupt or empty."""


class TopologyError(SurfidxError, ValueError):
    """The surface cannot be processed: not closed, not genus 0, disconnected."""


class BitstreamError(SurfidxError, ValueError):
    """A compressed stream is damaged, truncated, foreign or of an unknown version."""


class DatabaseError(SurfidxError):
    """A database is foreign, of an unknown schema version, or a record is missing."""
