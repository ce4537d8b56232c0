"""A textured model read and coded as ``ingest`` reads and codes it, for the texture benchmarks.

``ingest`` reads a model with :func:`surfidx.topology.read_model` (one surfel per mesh vertex;
a surface of higher genus cut at its handles, the cuts closed by virtual patches, pieces as
parts) and codes it with one :class:`surfidx.codec.PartsEncoder` whose colour source is the
textured mesh, so that the colour grid is sampled from the texture itself, not from the
surfels' vertex colours. :func:`read_textured` and :func:`parts_encoder` do the same.
"""

from __future__ import annotations

import warnings

__all__ = ["read_textured", "parts_encoder", "real_surfels"]


def read_textured(path, texture=None):
    """The model as ``ingest`` reads it (a :class:`surfidx.topology.RepairedModel`)."""
    from surfidx.topology import read_model

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_model(path, **({} if texture is None else {"texture": texture}))


def real_surfels(model):
    """The model's surfels without its virtual patches': the input's own (the rate's
    denominator)."""
    s = model.surfels
    return s if s.patch is None else s.subset(~s.virtual)


def parts_encoder(model, options=None):
    """A :class:`surfidx.codec.PartsEncoder` of the model as ``ingest`` makes it, with
    ``options`` (a :class:`surfidx.codec.CodecOptions`, default the codec's)."""
    from surfidx.codec import PartsEncoder

    return PartsEncoder(list(model.parts), texture=model.texture, options=options,
                        face_patches=[model.face_patch(i) for i in range(len(model.parts))])
