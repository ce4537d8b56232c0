"""The switches and tuning values of the spherical map, in one frozen object.

:func:`surfidx.sphere.parameterize` takes ``options=MapOptions(...)``; the default object gives
the default map. Every stage stops on counts of steps or rounds, never on the clock, so a map
depends on its input and these options only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import InputError
from ..validate import check_option_fields, option

__all__ = ["MapOptions", "DEFAULT_OPTIONS", "METHODS", "STAGES"]

METHODS = ("tutte", "mds")
"""Names of the map's methods, accepted by :func:`surfidx.sphere.parameterize` (the first is
the default), by the codec and by the CLI."""

STAGES = ("multilevel", "single_level", "proxy", "repair", "realise", "mds")
"""Names of the stage records of a :class:`surfidx.sphere.SphericalMap`, in the order they run."""

_INF = math.inf



@dataclass(frozen=True)
class MapOptions:
    """Tuning of :func:`surfidx.sphere.parameterize`.

    Attributes
    ----------
    method : {"tutte", "mds"}
        ``"tutte"``: fold-free Tutte embedding with area balancing; ``"mds"``: the original
        spherical MDS of landmark geodesics.
    seed : int
        Seed of the landmark choice.
    landmarks : int
        Landmarks for the stress figure and for ``"mds"`` (at least 4).
    iterations : int
        Most area-reweighting iterations (``"tutte"``) or CG iterations / 10 (``"mds"``).
    gamma : float
        Exponent of the area reweighting, in (0, 2].
    balance : bool
        Untangle and balance the distortion at each level (False: the Tutte start, a level
        whose prolongation folds falls back to the single-level map; for tests and
        comparisons).
    coarse_ladder : tuple of int
        Coarsest sizes (vertices) of the multilevel hierarchy, tried in turn while a level cannot
        be untangled. A prolonged map of a few dozen vertices can fold so deeply (a thin frame,
        long fingers) that untangling, which on the sphere has no fixed boundary, collapses the
        map; another hierarchy rarely does. When every size fails, the single-level map (which
        squeezes every limb) is the last resort.
    embedded_hierarchy : bool
        Where every size of ``coarse_ladder`` fails and the single-level map squeezes the
        surface beyond ``max_area_distortion``, map it by one more hierarchy instead: decimated
        to ``coarse_ladder[0]`` with topology checks only and prolonged so that every level
        starts embedded (each removed vertex placed in its ring's kernel where the mean would
        fold it), which cannot fail to untangle. Where the single-level map is accepted it is
        kept: where both apply, the single-level map can leave fewer folds.
    level_ratio : int
        Each level has this many times the vertices of the next coarser one (≥ 2).
    level_steps : int
        Most balancing steps at each level but the finest.
    final_steps : int
        Most balancing steps at the finest level: long limbs keep gaining area after
        ``level_steps``.
    final_steps_large : int
        ... at a finest level above ``large_level`` vertices, where a step costs far more.
    large_level : int
        Vertex count above which a level is large: ``final_steps_large`` and the loose stop.
    strict_tol, strict_patience : float, int
        A level's balancing stops when ``strict_patience`` steps in a row lower the energy by
        less than the fraction ``strict_tol``.
    loose_tol, loose_patience : float, int
        The same stop on large levels.
    untangle_rounds : int
        Most ``eps`` rounds of untangling at each level.
    inverted_kept : float
        Share of a level's triangles that may stay inverted after untangling; beyond it the
        hierarchy fails and the next coarsest size is tried.
    energy_lambda : float
        Area weight ``λ`` of the balancing energy ``Σ A (‖J‖²/det + λ (det + 1/det))``
        (against angle preservation).
    single_level_work : float
        The single-level map balances at most ``single_level_work / n`` steps for ``n``
        vertices, clipped to ``[single_level_min_steps, single_level_max_steps]``: its cost per
        step grows with ``n``, so the bound on steps times vertices bounds its cost on any input.
    single_level_min_steps, single_level_max_steps : int
        The clip of the single-level step count.
    reweight_smoothing : int
        Graph-smoothing passes of the log area ratio in the Tutte reweighting (a smooth
        reweighting keeps the map close to conformal).
    reweight_min_gamma : float
        The reweighting stops when its halved exponent falls below this.
    reweight_growth : float
        Factor of the exponent after an accepted reweighting step (at most ``gamma``).
    reweight_fold_share : float
        A reweighting step may leave at most the start's folded Delaunay triangles, or this
        share of all of them if that is more.
    centre_iterations : int
        Most Möbius steps of the normalisation of the area-weighted centre of mass.
    max_area_distortion : float
        A single-level fallback map whose area distortion exceeds this is refused
        (:class:`~surfidx.TopologyError`): the grid would miss the parts it squeezes.
    proxy_coarser : float
        A point cloud's last proxy mesh is built at this times the automatic grid resolution.
    repair_rounds : int
        Most rounds of the single-vertex fold repair.
    search_folds : int
        The random search follows the repair when at most this many folds are left.
    search_trials : int
        Most moves the random search draws per folded triangle.
    search_work : float
        The random search evaluates at most ``search_work / n`` moves in all (each costs
        ``O(n)``).
    second_pass : bool
        Where the repair leaves folds, try every move again with the Delaunay triangulation's
        unfolded triangles kept embedded too (their neighbourhoods propose other moves).
    realise : bool
        Where folds remain, choose the triangulation by edge flips and realise it as the
        Delaunay triangulation of moved points (:mod:`surfidx.sphere.circlepattern`).
    realise_rounds : int
        Most flip-and-realise rounds.
    flip_ladder : tuple of (bool, float)
        The flips tried in turn, ``(convex only, largest Delaunay violation of a flipped-in
        edge)``, when a realisation fails or is refused: any flips first, then milder ones.
    anneal_steps : int
        Flips the annealed search proposes before the flips alone are realised (0: none).
    anneal_temperature : float
        A flip that adds ``k`` folded triangles is taken with probability ``exp(-k / T)``.
    mds_placement_steps : int
        Gradient steps placing each non-landmark surfel in method ``"mds"``.
    """

    method: str = option("tutte", choices=METHODS)
    seed: int = 0
    landmarks: int = option(32, min=4)
    iterations: int = 40
    gamma: float = option(0.15, min=0, min_open=True, max=2)
    balance: bool = True
    coarse_ladder: tuple = (64, 256, 32)
    embedded_hierarchy: bool = True
    level_ratio: int = 4
    level_steps: int = 300
    final_steps: int = 1500
    final_steps_large: int = 600
    large_level: int = 20000
    strict_tol: float = 1e-7
    strict_patience: int = 20
    loose_tol: float = 1e-5
    loose_patience: int = 5
    untangle_rounds: int = 60
    inverted_kept: float = 1e-3
    energy_lambda: float = 0.5
    single_level_work: float = 6e7
    single_level_min_steps: int = 300
    single_level_max_steps: int = 3000
    reweight_smoothing: int = 20
    reweight_min_gamma: float = 0.02
    reweight_growth: float = 1.5
    reweight_fold_share: float = 1e-4
    centre_iterations: int = 60
    max_area_distortion: float = 4.0
    proxy_coarser: float = 0.8
    repair_rounds: int = 40
    search_folds: int = 30
    search_trials: int = 5000
    search_work: float = 2e7
    second_pass: bool = True
    realise: bool = True
    realise_rounds: int = 3
    flip_ladder: tuple = ((False, _INF), (True, _INF), (True, 1.0), (True, 0.3))
    anneal_steps: int = 200_000
    anneal_temperature: float = 0.3
    mds_placement_steps: int = 50

    def __post_init__(self):
        check_option_fields(self)
        if self.level_ratio < 2:
            raise InputError(f"MapOptions.level_ratio must be at least 2, got {self.level_ratio}")
        ladder = self.coarse_ladder
        if not (isinstance(ladder, tuple) and ladder and all(
                isinstance(c, int) and not isinstance(c, bool) and c >= 4 for c in ladder)):
            raise InputError("MapOptions.coarse_ladder must be a non-empty tuple of vertex "
                             f"counts >= 4, got {ladder!r}")
        flips = self.flip_ladder
        if not (isinstance(flips, tuple) and all(
                isinstance(r, tuple) and len(r) == 2 and isinstance(r[0], bool)
                and isinstance(r[1], (int, float)) and r[1] > 0 for r in flips)):
            raise InputError("MapOptions.flip_ladder must be a tuple of (convex: bool, "
                             f"max_violation > 0) pairs, got {flips!r}")


DEFAULT_OPTIONS = MapOptions()
"""The options of the default map."""
