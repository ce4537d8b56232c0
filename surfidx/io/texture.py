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

__all__ = ["read_texture", "check_texture", "image_array", "IMAGE_FORMATS",
           "DEFAULT_IMAGE_QUALITY", "check_image_options", "encode_image"]

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


#: Formats a texture is written in, with their file suffixes and MIME types.
IMAGE_FORMATS = {"png": (".png", "image/png"), "jpeg": (".jpg", "image/jpeg"),
                 "webp": (".webp", "image/webp")}
#: Quality of a JPEG or WebP texture when none is given (1 … 100).
DEFAULT_IMAGE_QUALITY = 90


def check_image_options(image_format="png", image_quality=None) -> tuple[str, int | None]:
    """The texture image's format and quality, checked once before anything is decoded.

    Parameters
    ----------
    image_format : {"png", "jpeg", "webp"}
        ``"jpg"`` is taken for ``"jpeg"``; any case.
    image_quality : int, optional
        1 … 100, JPEG and WebP only (default :data:`DEFAULT_IMAGE_QUALITY`); PNG is lossless.

    Returns
    -------
    format : str
    quality : int or None
        None for PNG.

    Raises
    ------
    InputError
        An unknown format, a quality out of range, or a quality for PNG.
    """
    from ..errors import InputError

    fmt = str(image_format).lower() if isinstance(image_format, str) else image_format
    fmt = "jpeg" if fmt == "jpg" else fmt
    if fmt not in IMAGE_FORMATS:
        raise InputError(f"unknown texture image format {image_format!r}; use one of "
                         + ", ".join(IMAGE_FORMATS))
    if fmt == "png":
        if image_quality is not None:
            raise InputError(f"image_quality={image_quality!r} was given for a PNG texture, "
                             "which is lossless; give it with jpeg or webp, or drop it")
        return fmt, None
    if image_quality is None:
        return fmt, DEFAULT_IMAGE_QUALITY
    if (isinstance(image_quality, bool) or not isinstance(image_quality, (int, np.integer))
            or not 1 <= image_quality <= 100):
        raise InputError(f"image_quality must be an integer from 1 to 100, got "
                         f"{image_quality!r}")
    return fmt, int(image_quality)


def encode_image(image, *, image_format: str = "png", image_quality: int | None = None) -> bytes:
    """A texture image's file bytes: PNG (lossless, zlib's default level 6, since level 9
    spends several times the CPU of the whole decode for a few per cent of the image), JPEG
    (4:2:0, baseline) or WebP (lossy, method 6) at a quality, the same bytes for the same image.

    Parameters
    ----------
    image : (h, w, 3) uint8
    image_format : {"png", "jpeg", "webp"}
    image_quality : int, optional
        See :func:`check_image_options`.

    Returns
    -------
    bytes
    """
    from PIL import Image

    fmt, quality = check_image_options(image_format, image_quality)
    im = Image.fromarray(np.ascontiguousarray(image, np.uint8), "RGB")
    buf = io.BytesIO()
    if fmt == "png":
        im.save(buf, format="PNG", compress_level=6)
    elif fmt == "jpeg":
        im.save(buf, format="JPEG", quality=quality, subsampling=2, optimize=True)
    else:
        im.save(buf, format="WEBP", quality=quality, method=6, exact=False)
    return buf.getvalue()
