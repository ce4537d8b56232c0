"""Regular files read within bounds, and the texture image beside an OBJ that names none.

Only regular files are read (a FIFO, a device, a socket or a link to one raises
:class:`NotRegularFile` unread), and never beyond the size a file had when it was opened, so a
file that grows while it is read cannot stall a reader. Ingestion hashes and pairs files with
these before any parsing; every command that reads an OBJ pairs its texture the same way.
"""

from __future__ import annotations

import os
import stat
import warnings
from pathlib import Path

__all__ = ["NotRegularFile", "not_regular", "open_regular", "file_pieces", "read_regular",
           "lines_of_regular", "find_texture", "pair_texture"]


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


def open_regular(path):
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


def file_pieces(path, read):
    """``read(file, n)`` pieces of a regular file (at most 1 MiB each) until the size it had
    when opened is read."""
    fh, size = open_regular(path)
    with fh:
        while size > 0:
            piece = read(fh, min(size, 1 << 20))
            if not piece:
                return
            size -= len(piece)
            yield piece


def read_regular(path) -> bytes:
    """The bytes of a regular file, at most its size when opened."""
    return b"".join(file_pieces(path, lambda fh, n: fh.read(n)))


def lines_of_regular(path):
    """The lines of a regular file, read no further than its size when opened."""
    return file_pieces(path, lambda fh, n: fh.readline(n))


def _texture_lines(path: Path):
    """The lines of an OBJ that can say whether it names a texture, decoded: every ``mtllib``
    and the first ``vt`` (one is enough to know there are texture coordinates)."""
    vt = False
    for line in lines_of_regular(path):
        if line.startswith(b"mtllib ") or (not vt and line.startswith(b"vt ")):
            vt = vt or line.startswith(b"vt ")
            yield line.decode("utf-8", "replace")


def _obj_needs_texture(path: Path) -> bool:
    """An OBJ with texture coordinates (``vt``) whose material libraries name no ``map_Kd``
    image, parsed as :func:`surfidx.io.read_mesh` parses them."""
    from .obj import material_library, mtl_texture_name, obj_statements   # numpy: on use

    st = obj_statements(_texture_lines(path), keys=("vt", "mtllib"))
    if not st["vt"]:
        return False
    for lib in st["mtllib"]:
        # a library outside the folder counts: the reader uses it with allow_outside_textures
        # and says it skips it without; a name not ending in .mtl is never read
        mtl, _ = material_library(path, lib, allow_outside=True)
        if mtl is None:
            continue
        try:
            text = read_regular(mtl).decode("utf-8", "replace")
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


def pair_texture(path):
    """:func:`find_texture` for a model a command reads without a texture given: the image it
    pairs, with a warning naming it (so the pairing is never silent), or None. A file that
    cannot be read for it gives None and is left to the reader's own error.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    pathlib.Path or None

    Warns
    -----
    UserWarning
        The image paired with an OBJ whose MTL names none.
    """
    try:
        found = find_texture(path)
    except OSError:
        return None
    if found is not None:
        warnings.warn(f"{path}: texture coordinates but no texture named by its MTL; using "
                      f"{found.name} beside it (pass a texture to choose another)", UserWarning,
                      stacklevel=2)
    return found
