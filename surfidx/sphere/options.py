"""The switches and tuning values of the spherical map, in one frozen object.

:func:`surfidx.sphere.parameterize` takes ``options=MapOptions(...)``; the default object gives
the default map. Every stage stops on counts of steps or rounds, never on the clock, so a map
depends on its input and these options only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from ..errors import InputError
from ..validate import check_option_fields, option

__all__ = ["MapOptions", "DEFAULT_OPTIONS", "METHODS", "STAGES", "MAP_VERSION"]

METHODS = ("tutte", "mds")
"""Names of the map's methods, accepted by :func:`surfidx.sphere.parameterize` (the first is
the default), by the codec and by the CLI."""

STAGES = ("multilevel", "proxy", "mds")
"""Names of the stage records of a :class:`surfidx.sphere.SphericalMap`, in the order they run."""

MAP_VERSION = 5
"""Version of the map's construction, stored with the data it produced (the codec's report):
2 is the map that embeds every level by construction (no fold repair), 3 the same map balanced
by vertex relaxation sweeps between runs of fewer L-BFGS steps, 4 the same with each batch of
sweeps stopped after one that gains less than ``sweep_tol`` and no sweeps in the balancing
after each round of a level prolonged round by round (``round_sweeps``), 5 the same map whose
grid level (:attr:`surfidx.sphere.SphericalMap.grid_level`) the sparse sampling raises to
level 8 at most (``SPARSE_MAX_LEVEL`` of :func:`surfidx.geometry.icosphere.choose_level`)."""


@dataclass(frozen=True)
class MapOptions:
    """Tuning of :func:`surfidx.sphere.parameterize`.

    Attributes
    ----------
    method : {"tutte", "mds"}
        ``"tutte"``: multilevel embedding with area balancing; ``"mds"``: the original
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
        Balance the distortion at each level (False: the Tutte start carried to every level
        unbalanced; for tests and comparisons).
    coarse_vertices : int
        Vertices of the coarsest level of the hierarchy (at least 4), mapped by the
        single-level route.
    level_ratio : int
        Each level has this many times the vertices of the next coarser one (≥ 2).
    level_steps : int
        Most L-BFGS balancing steps at each level but the finest.
    level_rounds : int
        Runs those steps are split into, each after ``relax_sweeps`` sweeps of vertex-by-vertex
        relaxation (:mod:`surfidx.sphere.relax`), with sweeps after the last run too.
    relax_sweeps : int
        Relaxation sweeps before each run of L-BFGS steps on every level but the finest (and
        in the single-level map).
    sweep_tol : float
        Every batch of relaxation sweeps stops after a sweep that lowers the level's energy by
        less than this fraction of it (0: all of them).
    settle_energy : float
        A level whose prolonged start has a balancing energy per unit area above this (4 for
        an isometry; kernel insertions nested in thin wedges give 1e10 and more, which the
        balancing cannot undo) is prolonged again round by round, each round's mesh balanced.
    round_steps : int
        Most balancing steps after each round of such a level.
    round_sweeps : int
        Relaxation sweeps before and after those steps (each round's mesh is balanced again
        by the next round and the whole level after the last, so a round needs few).
    final_steps : int
        Most L-BFGS balancing steps at the finest level.
    final_steps_large : int
        ... at a finest level above ``large_level`` vertices, where a step costs far more.
    query_final_steps, query_final_steps_large : int
        The same two counts for the map of a query by example (:meth:`for_query`): its
        descriptors are only compared with stored ones, and they find them as well after far
        fewer steps at the finest level, which take most of a map's time
        (``benchmarks/query_map.py``).
    final_rounds : int
        Runs the finest level's steps are split into, each after ``final_sweeps`` sweeps.
    final_sweeps : int
        Relaxation sweeps before each run at the finest level and after its last.
    large_level : int
        Vertex count above which a level is large: ``final_steps_large`` and the loose stop.
    strict_tol, strict_patience : float, int
        A level's balancing stops when ``strict_patience`` steps in a row lower the energy by
        less than the fraction ``strict_tol``.
    loose_tol, loose_patience : float, int
        The same stop on large levels.
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
    centre_iterations : int
        Most Möbius steps of the normalisation of the area-weighted centre of mass.
    mds_placement_steps : int
        Gradient steps placing each non-landmark surfel in method ``"mds"``.
    """

    method: str = option("tutte", choices=METHODS)
    seed: int = 0
    landmarks: int = option(32, min=4)
    iterations: int = 40
    gamma: float = option(0.15, min=0, min_open=True, max=2)
    balance: bool = True
    coarse_vertices: int = option(4, min=4)
    level_ratio: int = 4
    level_steps: int = 90
    level_rounds: int = option(3, min=1)
    relax_sweeps: int = option(10, min=0)
    sweep_tol: float = 1e-5
    settle_energy: float = 1e4
    round_steps: int = 10
    round_sweeps: int = option(0, min=0)
    final_steps: int = 600
    final_steps_large: int = 150
    query_final_steps: int = option(100, min=0)
    query_final_steps_large: int = option(50, min=0)
    final_rounds: int = option(2, min=1)
    final_sweeps: int = option(10, min=0)
    large_level: int = 20000
    strict_tol: float = 1e-7
    strict_patience: int = 20
    loose_tol: float = 1e-5
    loose_patience: int = 5
    energy_lambda: float = 0.5
    single_level_work: float = 6e7
    single_level_min_steps: int = 300
    single_level_max_steps: int = 3000
    reweight_smoothing: int = 20
    reweight_min_gamma: float = 0.02
    reweight_growth: float = 1.5
    centre_iterations: int = 60
    mds_placement_steps: int = 50

    def __post_init__(self):
        check_option_fields(self)
        if self.level_ratio < 2:
            raise InputError(f"MapOptions.level_ratio must be at least 2, got {self.level_ratio}")

    def for_query(self) -> "MapOptions":
        """These options with a query's finest-level step counts (``query_final_steps``,
        ``query_final_steps_large``) in place of an ingest's: how a query by example is mapped
        (:func:`surfidx.pipeline.describe_model` with ``for_query=True``)."""
        return replace(self, final_steps=self.query_final_steps,
                       final_steps_large=self.query_final_steps_large)


DEFAULT_OPTIONS = MapOptions()
"""The options of the default map."""
