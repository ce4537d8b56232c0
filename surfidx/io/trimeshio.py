"""The formats read through trimesh (STL, glTF, GLB) and trimesh objects in memory, as a
:class:`TriangleMesh` or points: vertices merged by exact position in order of first occurrence,
a base-colour texture or vertex colours kept."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError
from ..geometry.mesh import TriangleMesh
from .limits import check_coordinates
from .points import Points
from .texture import image_array


def merge_positions(vertices: np.ndarray):
    """Vertices merged by exact position, in order of first occurrence.

    STL's triangle soup and glTF's seams duplicate vertices; merged, the surface is closed
    where it is.

    Parameters
    ----------
    vertices : (n, 3) float64

    Returns
    -------
    unique : (u, 3) float64
    index : (n,) int64
        ``vertices == unique[index]``.
    """
    uniq, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return vertices[first[order]], rank[np.asarray(inverse).ravel()]


def _mesh_parts(tm, path):
    """``(vertices, faces, vertex colours or None, uv or None, texture or None)`` of one
    ``trimesh.Trimesh``: a base-colour texture (times its factor) with UVs, or vertex or face
    colours, or a uniform base colour."""
    verts = np.asarray(tm.vertices, np.float64)
    faces = np.asarray(tm.faces, np.int64)
    if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
        bad = int(faces.max()) if faces.max() >= len(verts) else int(faces.min())
        raise FileFormatError(f"a triangle refers to vertex {bad}, the mesh has {len(verts)}",
                              path=path)
    visual = tm.visual
    kind = getattr(visual, "kind", None)
    colors, uv, tex = None, None, None
    if kind == "texture":
        mat = getattr(visual, "material", None)
        image = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        factor = getattr(mat, "baseColorFactor", None)
        tex = image_array(image, path)
        if tex is not None and getattr(visual, "uv", None) is not None and \
                len(visual.uv) == len(verts):
            uv = np.asarray(visual.uv, np.float64)
            if factor is not None and image is getattr(mat, "baseColorTexture", None):
                f = np.asarray(factor, np.float64)[:3] / 255.0
                tex = np.clip(np.round(tex * f), 0, 255).astype(np.uint8)
        else:
            tex = None
            if factor is not None:
                colors = np.tile(np.asarray(factor, np.uint8)[:3], (len(verts), 1))
    elif kind in ("vertex", "face"):
        colors = np.asarray(visual.vertex_colors, np.uint8)[:, :3]
    return verts, faces, colors, uv, tex


def from_trimesh(obj, path=None, name=None):
    """A ``trimesh.Trimesh``, ``PointCloud`` or ``Scene`` as a :class:`TriangleMesh` (vertices
    merged by position, see :func:`merge_positions`) or as :class:`~surfidx.io.points.Points`.

    One textured mesh keeps its texture and UVs; several meshes are joined with their textures
    sampled at the vertices.

    Parameters
    ----------
    obj : trimesh.Trimesh, trimesh.PointCloud or trimesh.Scene
    path : pathlib.Path, optional
        Named in errors.
    name : str, optional

    Returns
    -------
    TriangleMesh or Points

    Raises
    ------
    FileFormatError
        When it holds no triangles and no points, or a triangle names a missing vertex.
    """
    import trimesh

    if isinstance(obj, trimesh.Scene):
        geoms = obj.dump(concatenate=False) if len(obj.geometry) else []
    else:
        geoms = [obj]
    meshes = [g for g in geoms if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    clouds = [g for g in geoms if isinstance(g, trimesh.PointCloud) and len(g.vertices)]
    if not meshes:
        if not clouds:
            raise FileFormatError("holds no triangles and no points", path=path)
        pos = np.vstack([np.asarray(c.vertices, np.float64) for c in clouds])
        cols = [getattr(c, "colors", None) for c in clouds]
        colors = None
        if all(c is not None and len(c) for c in cols):
            colors = np.vstack([np.asarray(c, np.uint8)[:, :3] for c in cols])
        return Points(check_coordinates(pos, path), None, colors)
    parts = [_mesh_parts(m, path) for m in meshes]
    if len(parts) == 1 and parts[0][4] is not None:
        verts, faces, colors, uv, tex = parts[0]
        merged, index = merge_positions(verts)
        return TriangleMesh(check_coordinates(merged, path), index[faces], uv=uv, uv_faces=faces,
                            texture=tex, name=name)
    # several parts: textures are sampled at the vertices (colours per vertex), then joined
    vs, fs, cs, base = [], [], [], 0
    for verts, faces, colors, uv, tex in parts:
        if tex is not None:
            from ..geometry.mesh import sample_texture

            colors = np.clip(np.round(sample_texture(tex, uv)), 0, 255).astype(np.uint8)
        vs.append(verts)
        fs.append(faces + base)
        cs.append(colors)
        base += len(verts)
    verts = np.vstack(vs)
    colors = np.vstack(cs) if all(c is not None for c in cs) else None
    merged, index = merge_positions(verts)
    if colors is not None:
        first = np.full(len(merged), -1, np.int64)
        first[index[::-1]] = np.arange(len(index))[::-1]
        colors = colors[first]
    return TriangleMesh(check_coordinates(merged, path), index[np.vstack(fs)],
                        vertex_colors=colors, name=name)


def read_trimesh(path: Path, resolver=None):
    """STL, glTF or GLB through trimesh (:func:`from_trimesh`).

    Parameters
    ----------
    path : pathlib.Path
    resolver : trimesh.resolvers.Resolver, optional
        What reads the files a glTF names (:func:`~surfidx.io.gltf.read_gltf` passes one
        bounded to the model's folder); trimesh's own by default.

    Returns
    -------
    TriangleMesh or Points

    Raises
    ------
    FileFormatError
        A file trimesh cannot read.
    """
    try:
        import trimesh
    except ImportError as exc:                              # pragma: no cover - a dependency
        raise FileFormatError(f"reading {path.suffix} needs trimesh ({exc})", path=path) \
            from None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(str(path), process=False, force=None, resolver=resolver)
    except MemoryError:
        raise
    except Exception as exc:  # trimesh raises many kinds on damaged input
        msg = str(exc).strip() or type(exc).__name__
        raise FileFormatError(f"not a readable {path.suffix.lstrip('.').upper()} file ({msg})",
                              path=path) from None
    try:
        return from_trimesh(loaded, path, name=path.stem)
    except OSError as exc:      # Pillow decodes a texture lazily, when trimesh copies it
        raise FileFormatError(f"cannot read the texture image ({exc})", path=path) from None
