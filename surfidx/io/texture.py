"""Texture images: read bounded (:func:`read_texture`, size checked before decoding) and only
in the image formats listed (Pillow is never asked to run an external decoder)."""

from __future__ import annotations

import io
import re
import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError, SurfidxError
from . import limits

#: Image formats a texture may have (Pillow is never asked to run an external decoder).
_TEXTURE_FORMATS = ("PNG", "JPEG", "BMP", "TGA", "TIFF", "GIF", "WEBP", "PPM")


def read_texture(path, *, _source: str = "") -> np.ndarray:
    """Read a texture image as (h, w, 3) uint8.

    Only PNG, JPEG, BMP, TGA, TIFF, GIF, WebP and PPM images of at most
    :data:`~surfidx.io.limits.MAX_TEXTURE_PIXELS` pixels are read; the size is checked before
    decoding.

    Raises
    ------
    FileFormatError
        Naming the image (and the file that refers to it) when it is missing, unreadable,
        damaged or too large.
    """
    path = Path(path)
    where = f" ({_source})" if _source else ""
    if not path.is_file():
        raise FileFormatError(f"texture image not found{where}", path=path)
    return _decode(path, path, where, decode=True)


def check_texture(source, path, where: str = "") -> tuple[int, int]:
    """The size of a texture image read from its header only, refused as :func:`read_texture`
    refuses it (a format not listed, a damaged header, more than
    :data:`~surfidx.io.limits.MAX_TEXTURE_PIXELS` pixels).

    A glTF's images are checked so before trimesh decodes them.

    Parameters
    ----------
    source : pathlib.Path or bytes
        The image file, or its bytes.
    path : pathlib.Path
        The file named in the error.
    where : str
        Which image of that file (``" (image 0)"``), appended to the message.

    Returns
    -------
    (int, int)
        Width and height.

    Raises
    ------
    FileFormatError
    """
    return _decode(source, path, where, decode=False)


def _decode(source, path, where, *, decode):
    """Open an image (a path or bytes) in the listed formats, check its size before decoding,
    then decode it as RGB (or return its size); every failure names ``path``."""
    from PIL import Image

    src = io.BytesIO(source) if isinstance(source, (bytes, bytearray, memoryview)) else source
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(src, formats=_TEXTURE_FORMATS)
        with im:
            w, h = im.size
            if w * h > limits.MAX_TEXTURE_PIXELS:
                raise FileFormatError(
                    f"texture image of {w} × {h} pixels exceeds the limit of "
                    f"{limits.MAX_TEXTURE_PIXELS:,} pixels{where}; scale it down", path=path)
            if not decode:
                return w, h
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)
                return np.asarray(im.convert("RGB"), dtype=np.uint8)
    except SurfidxError:
        raise
    except Image.DecompressionBombError as exc:
        size = re.search(r"\((\d+) pixels\)", str(exc))
        declared = f" (it declares {int(size.group(1)):,})" if size else ""
        raise FileFormatError(f"texture image exceeds the limit of {limits.MAX_TEXTURE_PIXELS:,} "
                              f"pixels{declared}{where}; scale it down", path=path) from None
    except MemoryError:
        raise
    except Exception as exc:  # Pillow raises many kinds on damaged images
        msg = str(exc).strip() or type(exc).__name__
        raise FileFormatError(f"cannot read the texture image ({msg}){where}", path=path) \
            from None


def image_array(image, path, where: str = "") -> np.ndarray | None:
    """A Pillow image opened by trimesh (a glTF's texture, its header already checked by
    :func:`check_texture`) decoded as (h, w, 3) uint8; None for None.

    Parameters
    ----------
    image : PIL.Image.Image or None
    path : pathlib.Path
        The model file, named in the error.
    where : str
        Which image of that file, appended to the message.

    Returns
    -------
    (h, w, 3) uint8 or None

    Raises
    ------
    FileFormatError
        An image of more than :data:`~surfidx.io.limits.MAX_TEXTURE_PIXELS` pixels, or one
        that fails to decode (truncated, damaged), naming ``path``.
    """
    if image is None:
        return None
    w, h = image.size
    if w * h > limits.MAX_TEXTURE_PIXELS:
        raise FileFormatError(f"texture image of {w} × {h} pixels exceeds the limit of "
                              f"{limits.MAX_TEXTURE_PIXELS:,} pixels{where}; scale it down",
                              path=path)
    try:
        return np.asarray(image.convert("RGB"), dtype=np.uint8)
    except MemoryError:
        raise
    except Exception as exc:  # Pillow raises many kinds on damaged images
        msg = str(exc).strip() or type(exc).__name__
        raise FileFormatError(f"cannot read the texture image ({msg}){where}", path=path) \
            from None
