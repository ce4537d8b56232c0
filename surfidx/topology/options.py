"""The repair's switches and tuning values, frozen and passed explicitly."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError
from ..validate import check_option_fields

__all__ = ["RepairOptions"]


@dataclass(frozen=True)
class RepairOptions:
    """Tuning of :func:`surfidx.topology.close_surface` and :func:`~surfidx.topology.split_parts`.

    Attributes
    ----------
    min_part_vertices : int
        :func:`split_parts` drops a component with fewer vertices than this (never the largest).
    min_part_share : float
        ... or with fewer than this share of all used vertices (0.01: under 1 %).
    dp_max_loop : int
        Holes with at most this many rim vertices are triangulated by the O(n³) dynamic programme
        (Liepa 2003: lexicographic (largest dihedral angle, area)); longer rims are first split
        by short chords into pieces of at most this many (O(n log n)). The programme's cost
        grows as the cube of the rim, so the default keeps each piece cheap against the rest
        of the repair; ``benchmarks/topology.py --dp`` prints the time of closing one hole by rim
        length, with and without the split.
    refine_ratio : float
        Patch edges longer than this many times the hole's mean rim edge length are bisected.
    patch_vertex_factor : float
        A patch gets at most about this many interior vertices per rim vertex (plus
        ``patch_vertex_floor``): beyond, the target edge length grows so that a hole the size of
        a fragment's whole back does not outnumber the scan.
    patch_vertex_floor : int
        See ``patch_vertex_factor``.
    flip_rounds : int
        Rounds of Delaunay edge flips inside the refined patches.
    handle_roots : int
        Roots tried for the greedy homotopy generators of each handle cut (farthest-point
        sequence); the shortest generator loop over all of them is cut.
    rim_penalty : float
        Edge-length factor of the edges touching a boundary vertex in the search of the cut
        cycle, so that cuts keep away from holes.
    """

    min_part_vertices: int = 50
    min_part_share: float = 0.01
    dp_max_loop: int = 300
    refine_ratio: float = 1.5
    patch_vertex_factor: float = 2.0
    patch_vertex_floor: int = 200
    flip_rounds: int = 8
    handle_roots: int = 4
    rim_penalty: float = 4.0

    def __post_init__(self):
        check_option_fields(self)
        if self.dp_max_loop < 3:
            raise InputError(f"RepairOptions.dp_max_loop must be at least 3, got "
                             f"{self.dp_max_loop}")
        if self.handle_roots < 1:
            raise InputError("RepairOptions.handle_roots must be at least 1, got "
                             f"{self.handle_roots}")
        if self.min_part_share >= 1:
            raise InputError(f"RepairOptions.min_part_share must be below 1, got "
                             f"{self.min_part_share}")
        if self.refine_ratio < 0.5:
            raise InputError(f"RepairOptions.refine_ratio must be at least 0.5, got "
                             f"{self.refine_ratio}")
        if self.rim_penalty < 1:
            raise InputError(f"RepairOptions.rim_penalty must be at least 1, got "
                             f"{self.rim_penalty}")
