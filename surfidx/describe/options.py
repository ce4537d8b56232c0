"""The descriptors' settings, in one frozen object (:class:`DescribeOptions`)."""

from __future__ import annotations

from dataclasses import dataclass

from ..validate import check_option_fields, option

__all__ = ["DescribeOptions", "DEFAULT_LMAX"]

DEFAULT_LMAX = 24
"""Largest spherical-harmonic degree of the ``layers`` and ``texture`` descriptor vectors."""


@dataclass(frozen=True)
class DescribeOptions:
    """Settings of :func:`surfidx.describe.describe_grid` as the pipeline calls it.

    Attributes
    ----------
    lmax : int
        Largest spherical-harmonic degree of the ``layers``/``texture`` vectors (at least 1);
        two models compare only when it is equal.
    query_level : int
        Grid level at most of a query by example's description
        (:func:`surfidx.pipeline.describe_model` with ``for_query=True``, unless a level is
        given): the descriptors are computed at resolutions of their own, which a finer grid
        hardly changes, while a level-8 grid's tables, resampling and description cost a
        query more than a second (``benchmarks/query_map.py``).
    """

    lmax: int = option(DEFAULT_LMAX, min=1)
    query_level: int = option(6, min=0, max=9)

    def __post_init__(self):
        check_option_fields(self)
