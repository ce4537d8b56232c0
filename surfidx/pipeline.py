"""The per-model work unit shared by the CLI, bulk ingestion (process pool) and the distributed
executor: read → map to the sphere → encode → describe → thumbnail, as one picklable result."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["ProcessedModel", "content_hash"]


@dataclass
class ProcessedModel:
    """Everything the database stores for one model (picklable, numpy + bytes only).

    Attributes
    ----------
    name : str
        Model name (file stem).
    source : str
        Path the model was read from (as given, resolved to absolute).
    content_hash : str
        SHA-256 hex of the model file's bytes and of its texture image's bytes, if any.
    n_surfels : int
        Surfels of the input (the rate denominator).
    has_color : bool
    bbox : (2, 3) float64
        Minimum and maximum corner of the input's bounding box.
    stream : bytes
        The compressed asset: a complete container file holding the embedded bitstream.
    format_version : int
        Bitstream container format version of ``stream``.
    rate : float
        Bits per input surfel of ``stream`` (whole file counted).
    quality : dict of str -> float or None
        ``psnr_d1``, ``psnr_d2``, ``psnr_y`` (None without colour) of ``stream`` decoded at full
        rate against the input.
    descriptors : dict of str -> (d,) float32
        Descriptor vectors by kind (``"shape"``, ``"texture"``, ``"spectrum"``).
    thumbnail : bytes
        PNG image of the decoded model.
    params : dict
        JSON-serialisable parameters that produced the record (grid level, map method, codec
        version, descriptor lmax and normalisation, ...).
    timings : dict of str -> float
        Seconds per stage.
    """

    name: str
    source: str
    content_hash: str
    n_surfels: int
    has_color: bool
    bbox: np.ndarray
    stream: bytes
    format_version: int
    rate: float
    quality: dict
    descriptors: dict
    thumbnail: bytes
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


def content_hash(path, *, texture=None) -> str:
    """SHA-256 hex digest of a model file (and of its texture image when one is given).

    Parameters
    ----------
    path : str or os.PathLike
    texture : str or os.PathLike, optional
    """
    h = hashlib.sha256()
    for p in (path, texture):
        if p is None:
            continue
        with open(Path(p), "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()
