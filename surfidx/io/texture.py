"""Texture images: read bounded (:func:`read_texture`, size checked before decoding) and only
in the image formats listed (Pillow is never asked to run an external decoder)."""

from __future__ import annotations

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
    from PIL import Image

    path = Path(path)
    where = f" ({_source})" if _source else ""
    if not path.is_file():
        raise FileFormatError(f"texture image not found{where}", path=path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            im = Image.open(path, formats=_TEXTURE_FORMATS)
        with im:
            w, h = im.size
            if w * h > limits.MAX_TEXTURE_PIXELS:
                raise FileFormatError(
                    f"texture image of {w} × {h} pixels exceeds the limit of "
                    f"{limits.MAX_TEXTURE_PIXELS:,} pixels{where}; scale it down", path=path)
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
    except Exception as exc:  # Pillow raises many kinds on damaged images
        msg = str(exc).strip() or type(exc).__name__
        raise FileFormatError(f"cannot read the texture image ({msg}){where}", path=path) \
            from None


def image_array(image, path) -> np.ndarray | None:
    """A decoded Pillow image (a glTF's texture) as (h, w, 3) uint8, refused when it has more
    than :data:`~surfidx.io.limits.MAX_TEXTURE_PIXELS` pixels; None for None.

    Parameters
    ----------
    image : PIL.Image.Image or None
    path : pathlib.Path
        The model file, named in the error.

    Returns
    -------
    (h, w, 3) uint8 or None
    """
    if image is None:
        return None
    w, h = image.size
    if w * h > limits.MAX_TEXTURE_PIXELS:
        raise FileFormatError(f"texture image of {w} × {h} pixels exceeds the limit of "
                              f"{limits.MAX_TEXTURE_PIXELS:,} pixels; scale it down", path=path)
    return np.asarray(image.convert("RGB"), dtype=np.uint8)
