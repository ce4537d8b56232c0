"""Spherical map of a closed genus-0 surfel set that does not fold.

The stages of the default method ``"tutte"``, one module each:

0. :mod:`.surface`: the mesh faces (``SurfelSet.faces``) are checked to triangulate a sphere
   (closed, one piece, manifold, genus 0, consistent winding) before any mapping, so a torus or
   two pieces fail with :class:`~surfidx.TopologyError`.
1. :mod:`.multilevel` with :mod:`.decimate`: rounds of independent half-edge collapses under
   the link condition shrink the mesh by ``level_ratio`` per level down to a few dozen vertices;
   every level triangulates the same sphere. A Tutte map squeezes a limb by
   ``exp(-2π length / girth)`` at any resolution; a mesh of a few dozen vertices has no limbs to
   squeeze.
2. :mod:`.tutte`: the coarsest mesh gets the single-level map: a Tutte embedding with positive
   mean-value weights (fold-free by Tutte's theorem), area reweighting, balancing.
3. Each finer level: the removed vertices come back at the mean-value combination of their
   ring's sphere positions; the triangles this folds are untangled (Garanzha et al. 2021;
   :func:`.balance.untangle`); then the map is balanced by L-BFGS on the energy
   ``Σ A (‖J‖²/det + λ (det + 1/det))`` of the map from each 3D triangle to its chord triangle,
   preconditioned by the 3D cotangent Laplacian, with a line search that rejects any inverted
   triangle (:func:`.balance.balance`). The energy is smallest for a similarity of unit area
   ratio and grows without bound as a triangle degenerates, so every accepted iterate is a
   fold-free embedding; it trades angle against area distortion, so limbs keep the share of the
   sphere the grid needs. A Möbius normalisation ends each level: the area-weighted centre of
   mass at the origin, which makes the map canonical up to a rotation.
   A level that cannot be untangled fails its hierarchy; other coarsest sizes are tried
   (``MapOptions.coarse_ladder``), and when every one fails the whole surface gets the
   single-level map (the *fallback*). Where that squeezes parts of the surface to nothing, the
   *embedded hierarchy* (``MapOptions.embedded_hierarchy``) maps it instead: decimated under
   the link condition alone, each removed vertex that the mean would fold put into the kernel of
   its ring, so that every level starts embedded and none can fail (thin frames such as CAD
   chairs need it); a squeezed fallback that remains is refused.
4. :mod:`.repair`: the folded triangles of the spherical Delaunay triangulation of the mapped
   surfels (where the map is anisotropic) are lowered by single-vertex moves
   (:mod:`.foldrepair`), a second pass, and edge flips realised as the exact Delaunay
   triangulation of moved points by a circle pattern (:mod:`.circlepattern`), each realisation
   kept only when the resampling loses at most ``TOL.realise_loss``.

Point clouds (surfels without faces) are mapped through a closed proxy mesh (:mod:`.proxy`,
:mod:`.cloud`); each surfel takes the sphere position of its closest point on the proxy, and
stage 4 repairs the surfels' own Delaunay triangulation. The original method ``"mds"``
(:mod:`.mds`) is spherical MDS of landmark geodesics.

All stages use intrinsic quantities only (lengths, angles, areas, connectivity; ties broken by
index), and stop on counts of steps or rounds, never on the clock: the map depends on the input
and :class:`MapOptions` only, and a rotated input gives the same points up to a rotation.
Quality figures are in :mod:`.quality`; geometry on the unit sphere in :mod:`surfidx.geometry.unitsphere`.

:func:`parameterize` and its :class:`SphericalMap` live in :mod:`.mapping`, the method names and
:class:`MapOptions` in :mod:`.options`; this package exports them.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
