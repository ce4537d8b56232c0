"""Spherical map of a closed genus-0 surfel set, an embedding by construction.

Every step of the default method ``"tutte"`` keeps every mesh triangle counter-clockwise on the
sphere (``det[a, b, c] > 0`` for its corners), so the map covers the sphere once and nothing
needs repair afterwards. The steps, one module each:

0. :mod:`.surface`: the mesh faces (``SurfelSet.faces``) are checked to triangulate a sphere
   (closed, one piece, manifold, genus 0, consistent winding) before any mapping, so a torus or
   two pieces fail with :class:`~surfidx.TopologyError`.
1. :mod:`.decimate`: rounds of independent half-edge collapses under the link condition shrink
   the mesh by ``level_ratio`` per level down to a tetrahedron (or as far as collapses go);
   every level triangulates the same sphere, and each removed vertex remembers its ring.
2. :mod:`.tutte`: the coarsest mesh gets a Tutte embedding with positive mean-value weights
   (an embedding of the plane by Tutte's theorem), lifted by the inverse stereographic
   projection of the plane scaled until every triangle is counter-clockwise, area reweighting
   and balancing.
3. :mod:`.multilevel`: each finer level starts from the coarser map (Praun & Hoppe 2003): a
   removed vertex comes back at the mean-value combination of its ring's sphere positions, or,
   where that would turn a triangle of its star over, inside the kernel of its ring, and is
   placed by a pattern search over its star's conformal energy that never leaves the kernel
   (:meth:`.decimate.Hierarchy.prolong`); the rounds of one level have disjoint stars, so the
   start is an embedding. :mod:`.balance` then lowers the energy
   ``Σ A (‖J‖²/det + λ (det + 1/det))`` of the map from each 3D triangle to its chord triangle
   by L-BFGS, preconditioned by the 3D cotangent Laplacian, with a line search that takes a
   step only when no triangle degenerates anywhere along it (the exact form of the Smith &
   Schaefer step bound), so every iterate is an embedding. Its runs alternate with sweeps of
   :mod:`.relax`, which move one vertex at a time on its star's energy and open up the
   squeezed stars that would cut the global steps short (a batch of sweeps stops after one that
   lowers the energy by less than ``sweep_tol`` of it). The energy is smallest for a
   similarity of unit area ratio, so limbs keep the share of the sphere the grid needs. A level
   whose start is squeezed beyond ``settle_energy`` (kernels nested in thin wedges round after
   round) is prolonged again with each round's mesh balanced. A Möbius normalisation that turns
   no triangle over ends each level: the area-weighted centre of mass at the origin, which makes
   the map canonical up to a rotation.

The codec interpolates in the mesh's own faces (:func:`surfidx.codec.resample.map_triangles`),
so the folds that count are those of the mesh: :attr:`SphericalMap.folded` is 0. Point clouds
(surfels without faces) are mapped through a closed proxy mesh (:mod:`.proxy`, :mod:`.cloud`):
the proxy is embedded, each surfel takes the sphere position of its closest point on it, and the
codec interpolates in the spherical Delaunay triangulation of the surfels. The original method
``"mds"`` (:mod:`.mds`) is spherical MDS of landmark geodesics.

All steps use intrinsic quantities only (lengths, angles, areas, connectivity; ties broken by
index), and stop on counts of steps or rounds, never on the clock: the map depends on the input
and :class:`MapOptions` only, and a rotated input gives the same points up to a rotation.
Quality figures are in :mod:`.quality`; geometry on the unit sphere in
:mod:`surfidx.geometry.unitsphere`.

:func:`parameterize` and its :class:`SphericalMap` live in :mod:`.mapping`, the method names and
:class:`MapOptions` in :mod:`.options`; this package exports them.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
