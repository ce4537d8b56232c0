"""The one options tree of a model's processing (:class:`ProcessOptions`): the repair's, the
map's, the codec's and the descriptors' settings plus the few that belong to the model, from the
command line (``--options FILE``) to the kernels, and stored with every model."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, is_dataclass, replace

from .codec.options import CodecOptions
from .describe.options import DescribeOptions
from .errors import InputError
from .geometry.axes import UP_AXES
from .sphere.options import MapOptions
from .topology.options import RepairOptions
from .validate import check_option_fields, option

__all__ = ["ProcessOptions", "DEFAULT_THUMBNAIL_SIZE"]

DEFAULT_THUMBNAIL_SIZE = 192
"""Thumbnail width and height in pixels (a stored model's and a query example's)."""

_PARTS = {"repair": RepairOptions, "map": MapOptions, "codec": CodecOptions,
          "describe": DescribeOptions}


@dataclass(frozen=True)
class ProcessOptions:
    """Every setting of :func:`surfidx.pipeline.process_model`, one frozen tree.

    Attributes
    ----------
    repair : surfidx.topology.RepairOptions
    map : surfidx.sphere.MapOptions
    codec : surfidx.codec.CodecOptions
    describe : surfidx.describe.DescribeOptions
    samples : int or None
        Sample this many surfels uniformly over a mesh instead of one per vertex (at least 4).
    thumbnail_size : int
        Thumbnail width and height in pixels, 1 … 8192.
    up : str or None
        The model axis that points up (one of :data:`surfidx.geometry.axes.UP_AXES`, ``"+z"``),
        which the thumbnail shows upwards (:func:`surfidx.render.thumbnail_basis`); None: the
        file format's (:func:`surfidx.io.up_axis`: +y for meshes, +z for scanners' point
        clouds). Streams and descriptors do not depend on it.
    """

    repair: RepairOptions = field(default_factory=RepairOptions)
    map: MapOptions = field(default_factory=MapOptions)
    codec: CodecOptions = field(default_factory=CodecOptions)
    describe: DescribeOptions = field(default_factory=DescribeOptions)
    samples: int | None = option(None, min=4)
    thumbnail_size: int = option(DEFAULT_THUMBNAIL_SIZE, min=1, max=8192)
    up: str | None = option(None, choices=UP_AXES)

    def __post_init__(self):
        for name, cls in _PARTS.items():
            if not isinstance(getattr(self, name), cls):
                raise InputError(f"ProcessOptions.{name} must be a {cls.__name__}, got "
                                 f"{type(getattr(self, name)).__name__}")
        check_option_fields(self)

    def to_dict(self) -> dict:
        """The tree as plain JSON values (tuples as lists, infinity as ``"inf"``); it
        round-trips through :meth:`from_dict`."""
        return _plain(self)

    @classmethod
    def from_dict(cls, d, *, path=None) -> "ProcessOptions":
        """The tree from a (possibly partial) dict of :meth:`to_dict`'s form; missing keys keep
        their defaults.

        Raises
        ------
        InputError
            Naming ``path`` and the key, for an unknown key or a bad value.
        """
        if not isinstance(d, dict):
            raise InputError(f"options must be a table of settings, got {type(d).__name__}",
                             path=path)
        return _build(cls, d, "", path)

    @classmethod
    def load(cls, path) -> "ProcessOptions":
        """The tree from a ``.json`` or ``.toml`` file (:meth:`from_dict` of its contents).

        Raises
        ------
        InputError
            Naming the file: missing, not JSON or TOML, an unknown key or a bad value.
        """
        import json
        import tomllib
        from pathlib import Path

        p = Path(path)
        suffix = p.suffix.lower()
        if suffix not in (".json", ".toml"):
            raise InputError("an options file must end in .json or .toml", path=p)
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"cannot read options ({getattr(exc, 'strerror', None) or exc})",
                             path=p) from None
        try:
            d = json.loads(text) if suffix == ".json" else tomllib.loads(text)
        except (ValueError, tomllib.TOMLDecodeError) as exc:
            raise InputError(f"not valid {suffix[1:].upper()} ({exc})", path=p) from None
        return cls.from_dict(d, path=p)

    @classmethod
    def resolve(cls, options=None, *, bits_per_surfel=None, samples=None, level=None,
                method=None, thumbnail_size=None, lmax=None) -> "ProcessOptions":
        """``options`` (default ``ProcessOptions()``) with the pipeline's keywords that are
        given (not None) put in: what :func:`surfidx.pipeline.process_model` uses.

        Raises
        ------
        InputError
            ``options`` is not a ProcessOptions, a keyword's value is out of range.
        """
        from .sphere.options import METHODS

        if options is None:
            options = cls()
        elif not isinstance(options, cls):
            raise InputError(f"options must be a ProcessOptions, got {type(options).__name__}")
        if method is not None and method not in METHODS:
            raise InputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
        return options.updated(**{"codec.bits_per_surfel": bits_per_surfel, "samples": samples,
                                  "codec.level": level, "map.method": method,
                                  "thumbnail_size": thumbnail_size, "describe.lmax": lmax})

    def updated(self, **changes) -> "ProcessOptions":
        """A copy with dotted settings changed, None values ignored
        (``updated(**{"codec.bits_per_surfel": 4.0})``): command-line flags over a file."""
        d = {}
        for key, value in changes.items():
            if value is None:
                continue
            *parents, leaf = key.split(".")
            node = d
            for k in parents:
                node = node.setdefault(k, {})
            node[leaf] = value
        return _merge(self, d)


def _plain(value):
    """JSON form of an options value (dataclasses as dicts, tuples as lists, inf as "inf")."""
    if is_dataclass(value):
        return {f.name: _plain(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return value


def _typed(value, default):
    """A JSON value back in the form of the field's default: lists as tuples, "inf" as inf."""
    if isinstance(default, tuple) and isinstance(value, list):
        proto = default[0] if default else None
        return tuple(_typed(v, proto) for v in value)
    if isinstance(value, str) and value in ("inf", "+inf", "-inf", "Infinity", "-Infinity"):
        return -math.inf if value.startswith("-") else math.inf
    if isinstance(value, list):
        return tuple(_typed(v, None) for v in value)
    return value


def _build(cls, d, prefix, path):
    """``cls`` from the dict ``d``, unknown keys and bad values named with their dotted key."""
    names = {f.name: f for f in fields(cls)}
    unknown = sorted(set(d) - set(names))
    if unknown:
        raise InputError(f"unknown option {prefix + unknown[0]!r} (known here: "
                         f"{', '.join(names)})", path=path)
    kwargs = {}
    for k, v in d.items():
        sub = _PARTS.get(k) if cls is ProcessOptions else None
        if sub is not None:
            if not isinstance(v, dict):
                raise InputError(f"option {prefix + k!r} must be a table, got {v!r}", path=path)
            kwargs[k] = _build(sub, v, f"{prefix}{k}.", path)
        else:
            default = getattr(cls(), k) if cls is not ProcessOptions else None
            kwargs[k] = _typed(v, default)
    try:
        return cls(**kwargs)
    except InputError as exc:
        where = f" (in [{prefix[:-1]}])" if prefix else ""
        raise InputError(exc.reason + where, path=path) from None


def _merge(options, d):
    """``options`` with the (nested) dict ``d`` of new values applied (validated again)."""
    changes = {}
    for k, v in d.items():
        if isinstance(v, dict):
            changes[k] = _merge(getattr(options, k), v)
        else:
            changes[k] = v
    try:
        return replace(options, **changes)
    except TypeError as exc:
        raise InputError(f"unknown option ({exc})") from None
