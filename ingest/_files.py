"""Model files of an ingest: folders searched for them, files read within bounds, textures found.

Only regular files are read (a FIFO, a device, a socket or a link to one raises
:class:`NotRegularFile` unread), and never beyond the size a file had when it was opened, so a
file that grows while it is read cannot stall the run.
"""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path

from surfidx.errors import InputError

__all__ = ["discover", "NotRegularFile", "not_regular", "hash_files", "find_texture"]


# ---------------------------------------------------------------------- discovery
def discover(paths) -> list:
    """The model files named by ``paths``, absolute (symbolic links kept), deduplicated, sorted.

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        Files (taken as given, whatever their suffix or type) and folders (searched recursively
        for every suffix in ``surfidx.io.SUPPORTED_SUFFIXES``, case-insensitively; hidden entries
        skipped). Entries that are not regular files are listed too: :func:`make_tasks` skips
        them with the reason.

    Returns
    -------
    list of pathlib.Path

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
    empty_folders = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            before = len(found)
            for root, dirs, files in os.walk(p):
                dirs[:] = [d for d in dirs if not d.startswith(".")]
                for f in files:
                    if not f.startswith(".") and Path(f).suffix.lower() in SUPPORTED_SUFFIXES:
                        found.add(Path(os.path.abspath(Path(root, f))))
            if len(found) == before:
                empty_folders.append(p)
        elif p.exists():                            # a file, or a FIFO/device (skipped later)
            found.add(Path(os.path.abspath(p)))
        else:
            raise InputError("no such file or folder", path=p)
    if not found:
        raise InputError("holds no model file (supported: " + ", ".join(SUPPORTED_SUFFIXES)
                         + ")", path=empty_folders[0])
    for folder in empty_folders:
        import warnings

        warnings.warn(f"{folder}: holds no model file (supported: "
                      + ", ".join(SUPPORTED_SUFFIXES) + ")", UserWarning, stacklevel=2)
    return sorted(found)


# ---------------------------------------------------------------------- bounded reading
class NotRegularFile(OSError):
    """A path that is not a regular file (FIFO, device, socket, directory, or a link to one)."""


def _file_type(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "a named pipe (FIFO)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory")):
        if test(mode):
            return name
    return "not a regular file"


def not_regular(path, mode: int) -> NotRegularFile:
    """The :class:`NotRegularFile` error for ``path`` of file mode ``mode`` (its kind named)."""
    kind = _file_type(mode)
    link = os.path.islink(path)
    return NotRegularFile(f"not a regular file: {'a symbolic link to ' if link else ''}{kind}")


def _open_regular(path):
    """``(binary file, size)`` of a regular file, opened without blocking (opening a FIFO for
    reading would wait for a writer); anything else raises :class:`NotRegularFile`."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise not_regular(path, st.st_mode)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb"), st.st_size
    except BaseException:
        os.close(fd)
        raise


def _pieces(path, read):
    """``read(file, n)`` pieces of a regular file (at most 1 MiB each) until the size it had
    when opened is read."""
    fh, size = _open_regular(path)
    with fh:
        while size > 0:
            piece = read(fh, min(size, 1 << 20))
            if not piece:
                return
            size -= len(piece)
            yield piece


def _read_regular(path) -> bytes:
    """The bytes of a regular file, at most its size when opened."""
    return b"".join(_pieces(path, lambda fh, n: fh.read(n)))


def _lines_of_regular(path):
    """The lines of a regular file, read no further than its size when opened."""
    return _pieces(path, lambda fh, n: fh.readline(n))


def hash_files(path, *, texture=None) -> str:
    """SHA-256 hex of a model file's bytes and then its texture's (as
    ``surfidx.pipeline.content_hash``), reading regular files only and each no further than
    its size when opened.

    Raises
    ------
    NotRegularFile
        ``path`` or ``texture`` is a FIFO, device, socket or directory (or a link to one).
    OSError
        A file cannot be opened or read.
    """
    h = hashlib.sha256()
    for p in (path, texture):
        if p is not None:
            for chunk in _pieces(p, lambda fh, n: fh.read(n)):
                h.update(chunk)
    return h.hexdigest()


def _texture_lines(path: Path):
    """The lines of an OBJ that can say whether it names a texture, decoded: every ``mtllib``
    and the first ``vt`` (one is enough to know there are texture coordinates)."""
    vt = False
    for line in _lines_of_regular(path):
        if line.startswith(b"mtllib ") or (not vt and line.startswith(b"vt ")):
            vt = vt or line.startswith(b"vt ")
            yield line.decode("utf-8", "replace")


def _obj_needs_texture(path: Path) -> bool:
    """An OBJ with texture coordinates (``vt``) whose material libraries name no ``map_Kd``
    image, parsed as :func:`surfidx.io.read_mesh` parses them."""
    from surfidx.io.obj import mtl_texture_name, obj_statements

    st = obj_statements(_texture_lines(path), keys=("vt", "mtllib"))
    if not st["vt"]:
        return False
    for lib in st["mtllib"]:
        try:
            text = _read_regular(path.parent / lib).decode("utf-8", "replace")
        except OSError:
            continue
        if mtl_texture_name(text) is not None:
            return False
    return True


def find_texture(path):
    """The texture image of a textured OBJ whose UVs name none (like Keenan Crane's spot).

    For an OBJ with texture coordinates and no ``map_Kd`` in its material libraries, the first of
    these beside it is the texture: ``<stem>_texture.png``, ``<stem>.png``, or the only PNG of the
    folder. Any other file gets None.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    pathlib.Path or None

    Raises
    ------
    NotRegularFile
        ``path`` is an OBJ that is not a regular file.
    OSError
        ``path`` cannot be read.
    """
    path = Path(path)
    if path.suffix.lower() != ".obj" or not _obj_needs_texture(path):
        return None
    for name in (f"{path.stem}_texture.png", f"{path.stem}.png"):
        if (path.parent / name).is_file():
            return path.parent / name
    pngs = [p for p in path.parent.iterdir() if p.suffix.lower() == ".png" and p.is_file()]
    return pngs[0] if len(pngs) == 1 else None
