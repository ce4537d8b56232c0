"""The boundary validation helper: every public function converts its array arguments through
:func:`as_array`, so that messages are uniform and name the bad value and the fix."""

from __future__ import annotations

import math

import numpy as np

from .errors import InputError

__all__ = ["as_array", "check_positive_int", "check_option_fields", "option", "accepts_keyword"]


def as_array(value, name: str, *, dtype=np.float64, shape=None, finite: bool = True,
             min_len: int = 0, path=None) -> np.ndarray:
    """Convert ``value`` to a contiguous array and check it.

    Parameters
    ----------
    value : array_like
        The data.
    name : str
        Its name in messages (``"positions"``).
    dtype : numpy dtype
        Target dtype; integer targets reject non-integral floats.
    shape : tuple of (int or None), optional
        Expected shape; ``None`` entries match any length.
    finite : bool
        Reject NaN and infinity.
    min_len : int
        Smallest allowed length of the first axis.
    path : str, optional
        File the data came from, for the message.

    Returns
    -------
    numpy.ndarray
        C-contiguous array of ``dtype``.

    Raises
    ------
    InputError
        When conversion, shape, finiteness or length checks fail.
    """
    try:
        arr = np.asarray(value)
    except Exception as exc:  # pragma: no cover - numpy rarely fails here
        raise InputError(f"{name} cannot be converted to an array ({exc})", path=path) from exc
    if arr.dtype == object:
        raise InputError(f"{name} must be numeric, got ragged or object data", path=path)
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s is None or s == d for s, d in zip(shape, arr.shape))
        if not ok:
            parts = ["n" if s is None else str(s) for s in shape]
            want = "(" + ", ".join(parts) + (",)" if len(parts) == 1 else ")")
            raise InputError(f"{name} must have shape {want}, got {arr.shape}", path=path)
    target = np.dtype(dtype)
    if np.issubdtype(target, np.integer) and arr.size and not np.issubdtype(arr.dtype, np.integer):
        if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)) \
                or not np.all(arr == np.round(arr)):
            raise InputError(f"{name} must hold integers", path=path)
    if finite and arr.size and np.issubdtype(arr.dtype, np.floating):
        bad = ~np.isfinite(arr)
        if bad.any():
            first = int(np.argwhere(bad)[0][0])
            raise InputError(
                f"{name} contains {int(bad.sum())} NaN or infinite values (first at index {first});"
                " remove or repair them", path=path)
    if arr.ndim and arr.shape[0] < min_len:
        raise InputError(f"{name} needs at least {min_len} entries, got {arr.shape[0]}", path=path)
    return np.ascontiguousarray(arr, dtype=target)


def check_positive_int(value, name: str, *, minimum: int = 1) -> int:
    """Return ``value`` as int, raising :class:`InputError` unless it is an integer ≥ ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InputError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise InputError(f"{name} must be at least {minimum}, got {value}")
    return int(value)


_FIELD_CHECKS = {
    "bool": (lambda v: isinstance(v, bool), "True or False"),
    "int": (lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
            "an integer >= 0"),
    "float": (lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0
              and math.isfinite(v), "a finite number >= 0"),
}
"""Per annotated field type of an options dataclass: the test of a value and what the message
asks for."""


def check_option_fields(options) -> None:
    """Raise :class:`InputError` unless every ``bool``, ``int`` and ``float`` field of the frozen
    options dataclass ``options`` holds a value of its type (numbers >= 0, finite; ``X | None``
    fields may also hold None), and within the range its ``metadata`` declares (``min``,
    ``max``, ``min_open``, ``choices``); other fields are the class's own to check."""
    from dataclasses import fields

    for f in fields(options):
        value = getattr(options, f.name)
        kind = str(f.type)
        optional = kind.endswith(" | None")
        if optional:
            if value is None:
                continue
            kind = kind[:-len(" | None")]
        check = _FIELD_CHECKS.get(kind)
        what = f"{type(options).__name__}.{f.name}"
        if check is not None and not check[0](value):
            raise InputError(f"{what} must be {check[1]}{' or None' if optional else ''}, "
                             f"got {value!r}")
        meta = f.metadata
        if "choices" in meta and value not in meta["choices"]:
            raise InputError(f"{what} must be one of {', '.join(map(repr, meta['choices']))}, "
                             f"got {value!r}")
        lo, hi = meta.get("min"), meta.get("max")
        if lo is not None and (value <= lo if meta.get("min_open") else value < lo):
            raise InputError(f"{what} must be {'above' if meta.get('min_open') else 'at least'} "
                             f"{lo:g}, got {value!r}")
        if hi is not None and value > hi:
            raise InputError(f"{what} must be at most {hi:g}, got {value!r}")


def option(default, *, min=None, max=None, min_open: bool = False, choices=None):
    """A dataclass field with its allowed range declared beside it (read by
    :func:`check_option_fields`): ``min`` (exclusive with ``min_open``), ``max``, ``choices``."""
    from dataclasses import field

    meta = {k: v for k, v in (("min", min), ("max", max), ("choices", choices)) if v is not None}
    if min_open:
        meta["min_open"] = True
    return field(default=default, metadata=meta)


def accepts_keyword(func, name: str) -> bool:
    """Whether the callable ``func`` names a parameter ``name`` (as
    :func:`surfidx.pipeline.process_model` names ``progress`` and ``options``): a caller passes
    such a keyword only to a function that takes it, so user-supplied processors may omit it.

    Parameters
    ----------
    func : callable
    name : str

    Returns
    -------
    bool
        False also when ``func`` has no inspectable signature.
    """
    import inspect

    try:
        return name in inspect.signature(func).parameters
    except (TypeError, ValueError):
        return False
