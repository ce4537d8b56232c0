"""Reading and writing surfel sets, one module per format: surfel PLY, meshes (:mod:`.ply` with
faces or tristrips, :mod:`.obj` with MTL texture, :mod:`.off`, :mod:`.stl`, :mod:`.gltf` with
vertex colours or a base-colour texture) and point clouds (PLY, :mod:`.pcd`, :mod:`.xyz` for
XYZ and PTS, and the scanner formats :mod:`.las` for LAS/LAZ and :mod:`.e57`, through the
``scanners`` extra); :mod:`.registry` says which module reads and writes which suffix.

:mod:`.reading` reads models as they are (:func:`read_surfels`, :func:`read_mesh`,
:func:`as_surfels`, :func:`read_geometry`), never repairing (reading for storing, read then
repaired to closed genus-0 parts, is :func:`surfidx.topology.read_model`); :mod:`.writing` writes
PLY, OBJ and GLB (:func:`write_model`). Shared: :mod:`.limits` (bounds on what is read),
:mod:`.files` (regular files read within bounds, the texture beside an OBJ that names none),
:mod:`.originals` (the files a model is made of, for ``ingest --keep-original``),
:mod:`.texture`, :mod:`.atomic` (:func:`write_atomic`), :mod:`.points`, :mod:`.trimeshio`
(STL and glTF through trimesh), :mod:`.arrays`.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
