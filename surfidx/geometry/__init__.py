"""What every stage shares: the data and the geometry on it.

- :mod:`.surfels` — :class:`~surfidx.SurfelSet`, the oriented coloured disks every model becomes;
- :mod:`.mesh`, :mod:`.pointcloud` — triangle meshes and point clouds, converted to surfels;
- :mod:`.graph`, :mod:`.meshpaths`, :mod:`.geodesics` — the spheres-of-influence graph and
  geodesic distances and paths on it;
- :mod:`.unitsphere`, :mod:`.icosphere` — geometry on the unit sphere and the icosahedral grid;
- :mod:`.sparse` — the sparse symmetric positive-definite solver the map and descriptors use;
- :mod:`.metrics` — distortion as the field measures it (PSNR D1, D2, luma);
- :mod:`.closest` — the exact closest point of a mesh to many points;
- :mod:`.simplify` — a vertex budget met by quadric-error simplification;
- :mod:`.axes` — a model's up axis, as its file format keeps it.
- :mod:`.atlas` — a texture atlas of the icosahedral grid and colour baked into it.

The modules are imported one by one (``from surfidx.geometry.mesh import TriangleMesh``); their
public classes and functions are also top-level names of :mod:`surfidx`.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)
