"""glTF and GLB: meshes with vertex colours or a base-colour texture read through trimesh (a
``.gltf`` only with buffers in its own folder, unless allowed; a texture outside it skipped with
a warning); GLB written.

Before trimesh reads a file, :func:`check_gltf` checks what trimesh takes on trust: every
buffer, buffer view and accessor within the bytes behind it, every index below its vertex
count, every attribute as long as the positions, and the header of each base-colour image
(size, format). A damaged file is then one clear error instead of an ``IndexError`` or a
texture dropped without a word.
"""

from __future__ import annotations

import base64
import json
import struct
import urllib.parse
import warnings
from pathlib import Path

import numpy as np

from ..errors import FileFormatError
from .arrays import model_arrays
from .atomic import write_atomic
from .texture import check_texture
from .trimeshio import read_trimesh

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
#: Bytes per component, by glTF ``componentType``.
_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
#: numpy types of the index component types.
_INDEX_DTYPES = {5121: "u1", 5123: "<u2", 5125: "<u4"}
#: Components per element, by glTF accessor ``type``.
_TYPE_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: Primitive modes trimesh reads: points, triangles, triangle strips.
_READ_MODES = {0: "points", 4: "triangles", 5: "triangle strip"}
_MODE_NAMES = {1: "lines", 2: "line loop", 3: "line strip", 6: "triangle fan"}


def read_gltf(path: Path, allow_outside: bool = False):
    """Read a glTF or GLB model (:func:`~surfidx.io.trimeshio.read_trimesh`) once
    :func:`check_gltf` has checked it.

    Parameters
    ----------
    path : pathlib.Path
    allow_outside : bool
        Read buffers and images the file names outside its folder.

    Returns
    -------
    TriangleMesh or Points

    Raises
    ------
    FileFormatError
        What :func:`check_gltf` refuses, or a file trimesh cannot read.

    Warns
    -----
    UserWarning
        A base-colour image skipped (outside the folder, KTX2), a primitive not read (lines,
        fans).
    """
    skipped = check_gltf(path, allow_outside)
    return read_trimesh(path, resolver=_resolver(path, allow_outside, skipped))


def _int(value, what, path, *, minimum=0):
    """A JSON value that must be an integer of at least ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise FileFormatError(f"glTF {what} is {value!r}, not an integer of at least {minimum}",
                              path=path)
    return value


def _known(value, table) -> bool:
    """Whether a JSON value is one of a table's keys (lists and objects are not)."""
    return isinstance(value, (int, str)) and not isinstance(value, bool) and value in table


def _list(doc, key, path):
    items = doc.get(key, [])
    if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
        raise FileFormatError(f"glTF '{key}' is not a list of objects", path=path)
    return items


def _ref(value, items, what, path):
    """An index into a glTF array, checked."""
    i = _int(value, what, path)
    if i >= len(items):
        raise FileFormatError(f"glTF {what} is {i}, the file has {len(items)}", path=path)
    return i


def _uri_target(folder: Path, uri: str) -> Path:
    """The file a relative URI names (percent-escapes decoded), not resolved."""
    return folder / urllib.parse.unquote(uri)


def _inline(uri: str) -> bool:
    """Whether trimesh decodes a URI itself (base64) rather than asking the resolver."""
    return "base64," in uri


def _glb_layout(path: Path, size: int):
    """The JSON document and the binary chunk ``(offset, length)`` (or None) of a GLB."""
    with open(path, "rb") as fh:
        head = fh.read(20)
        if len(head) < 20 or head[:4] != _GLB_MAGIC:
            raise FileFormatError("not a readable GLB file (no glTF header)", path=path)
        version, length, json_len, json_type = struct.unpack("<IIII", head[4:])
        if version != 2:
            raise FileFormatError(f"not a readable GLB file (version {version}; only glTF 2 is "
                                  "read)", path=path)
        if json_type != _CHUNK_JSON or 20 + json_len > min(length, size):
            raise FileFormatError(f"not a readable GLB file (its header announces {length:,} "
                                  f"bytes and a JSON chunk of {json_len:,}, the file holds "
                                  f"{size:,}); it may be truncated", path=path)
        text = fh.read(json_len)
        binary = None
        offset = 20 + json_len
        if offset + 8 <= min(length, size):
            fh.seek(offset)
            bin_len, bin_type = struct.unpack("<II", fh.read(8))
            if bin_type == _CHUNK_BIN:
                if offset + 8 + bin_len > size:
                    raise FileFormatError(
                        f"GLB binary chunk announces {bin_len:,} bytes, the file holds "
                        f"{size - offset - 8:,} after it; it may be truncated", path=path)
                binary = (offset + 8, bin_len)
    return _parse_json(text, path), binary


def _parse_json(text: bytes, path: Path) -> dict:
    try:
        doc = json.loads(text.decode("utf-8"))
    except (ValueError, RecursionError) as exc:
        raise FileFormatError(f"not a readable glTF file ({exc})", path=path) from None
    if not isinstance(doc, dict):
        raise FileFormatError("not a readable glTF file (its JSON is not an object)", path=path)
    return doc


class _Buffer:
    """Where a glTF buffer's bytes are: inline (a data URI), or a span of a file."""

    def __init__(self, size, data=None, file=None, offset=0):
        self.size, self.data, self.file, self.offset = size, data, file, offset

    def read(self, start: int, length: int) -> bytes:
        if self.data is not None:
            return self.data[start:start + length]
        with open(self.file, "rb") as fh:
            fh.seek(self.offset + start)
            return fh.read(length)


def _buffers(doc, path, binary, allow_outside):
    """Each buffer's bytes located and checked against its ``byteLength``."""
    glb = binary is not None or path.suffix.lower() == ".glb"
    out = []
    for i, buf in enumerate(_list(doc, "buffers", path)):
        declared = _int(buf.get("byteLength"), f"buffer {i} byteLength", path)
        uri = buf.get("uri")
        if uri is None:
            if not glb or i != 0 or binary is None:
                raise FileFormatError(f"glTF buffer {i} has no uri (only a GLB's first buffer "
                                      "may refer to its binary chunk)", path=path)
            found = _Buffer(binary[1], file=path, offset=binary[0])
        elif not isinstance(uri, str):
            raise FileFormatError(f"glTF buffer {i} has a uri that is not text", path=path)
        elif _inline(uri):
            found = _Buffer(0, data=_data_uri(uri, f"buffer {i}", path))
            found.size = len(found.data)
        else:
            target = _uri_target(path.parent, uri)
            if not allow_outside and not target.resolve().is_relative_to(path.parent.resolve()):
                raise FileFormatError(
                    f"refers to {uri} outside the model's folder; allow it with "
                    "allow_outside_textures=True (--allow-outside-textures)", path=path)
            if not target.is_file():
                raise FileFormatError(f"glTF buffer {i} names {uri}, which is not a file "
                                      "beside it", path=path)
            found = _Buffer(target.stat().st_size, file=target)
        if found.size < declared:
            raise FileFormatError(f"glTF buffer {i} announces {declared:,} bytes and holds "
                                  f"{found.size:,}; the file may be truncated", path=path)
        out.append(found)
    return out


def _data_uri(uri: str, what: str, path: Path) -> bytes:
    try:
        return base64.b64decode(uri[uri.index("base64,") + 7:])
    except ValueError as exc:
        raise FileFormatError(f"glTF {what} has a damaged base64 data URI ({exc})",
                              path=path) from None


def _views(doc, buffers, path):
    """Each buffer view as ``(buffer, start, length, stride or None)``, within its buffer."""
    out = []
    for i, view in enumerate(_list(doc, "bufferViews", path)):
        b = _ref(view.get("buffer"), buffers, f"bufferView {i} buffer", path)
        start = _int(view.get("byteOffset", 0), f"bufferView {i} byteOffset", path)
        length = _int(view.get("byteLength"), f"bufferView {i} byteLength", path)
        stride = view.get("byteStride")
        if stride is not None:
            stride = _int(stride, f"bufferView {i} byteStride", path, minimum=1)
        if start + length > buffers[b].size:
            raise FileFormatError(f"glTF bufferView {i} spans bytes {start:,} to "
                                  f"{start + length:,} of buffer {b}, which holds "
                                  f"{buffers[b].size:,}; the file is damaged", path=path)
        out.append((b, start, length, stride))
    return out


def _accessors(doc, views, budget, path):
    """Each accessor as ``(count, element bytes, component type)``, its elements within its
    buffer view; accessors without one (zeros trimesh allocates) within ``budget`` bytes."""
    out = []
    zeros = 0
    for i, acc in enumerate(_list(doc, "accessors", path)):
        ctype = acc.get("componentType")
        kind = acc.get("type")
        if not _known(ctype, _COMPONENT_BYTES) or not _known(kind, _TYPE_WIDTH):
            raise FileFormatError(f"glTF accessor {i} has an unknown componentType {ctype!r} "
                                  f"or type {kind!r}", path=path)
        count = _int(acc.get("count"), f"accessor {i} count", path, minimum=1)
        elem = _COMPONENT_BYTES[ctype] * _TYPE_WIDTH[kind]
        if "bufferView" in acc:
            v = _ref(acc["bufferView"], views, f"accessor {i} bufferView", path)
            start = _int(acc.get("byteOffset", 0), f"accessor {i} byteOffset", path)
            stride = views[v][3] or elem
            end = start + (count - 1) * stride + elem
            if stride < elem or end > views[v][2]:
                raise FileFormatError(
                    f"glTF accessor {i} reads {count:,} elements of {elem} bytes every "
                    f"{stride} from byte {start:,} of bufferView {v}, which holds "
                    f"{views[v][2]:,} bytes; the file is damaged", path=path)
        else:
            zeros += count * elem
            if zeros > budget:
                raise FileFormatError(
                    f"glTF accessor {i} announces {count:,} elements with no data behind them "
                    f"(no bufferView), more than the file's {budget:,} bytes could hold; the "
                    "file is damaged", path=path)
        out.append((count, elem, ctype))
    return out


def _index_values(doc, views, buffers, i):
    """The values of index accessor ``i`` (its bounds already checked)."""
    acc = doc["accessors"][i]
    b, vstart, _, stride = views[acc["bufferView"]]
    dtype = np.dtype(_INDEX_DTYPES[acc["componentType"]])
    count = acc["count"]
    stride = stride or dtype.itemsize
    start = vstart + acc.get("byteOffset", 0)
    raw = buffers[b].read(start, (count - 1) * stride + dtype.itemsize)
    return np.lib.stride_tricks.as_strided(np.frombuffer(raw, np.uint8), (count, dtype.itemsize),
                                           (stride, 1)).copy().view(dtype).ravel()


def _check_primitives(doc, accessors, views, buffers, path):
    """Each mesh primitive: its accessors exist, hold data, agree in count, and its indices
    name existing vertices; primitives trimesh does not read are named in a warning."""
    accs = doc.get("accessors", [])
    for m, mesh in enumerate(_list(doc, "meshes", path)):
        prims = mesh.get("primitives", [])
        if not isinstance(prims, list) or not all(isinstance(p, dict) for p in prims):
            raise FileFormatError(f"glTF mesh {m} has no list of primitives", path=path)
        for p, prim in enumerate(prims):
            where = f"mesh {m}, primitive {p}"
            mode = prim.get("mode", 4)
            if not _known(mode, _READ_MODES):
                name = _MODE_NAMES[mode] if _known(mode, _MODE_NAMES) else f"mode {mode!r}"
                warnings.warn(f"{path}: {where} draws {name}, which is not read; skipped",
                              UserWarning, stacklevel=3)
                continue
            attrs = prim.get("attributes")
            if not isinstance(attrs, dict) or "POSITION" not in attrs:
                raise FileFormatError(f"glTF {where} has no POSITION attribute", path=path)
            refs = {name: _ref(a, accessors, f"{where} attribute {name}", path)
                    for name, a in attrs.items()}
            pos = refs["POSITION"]
            if "bufferView" not in accs[pos]:
                raise FileFormatError(
                    f"glTF {where}: its positions (accessor {pos}) have no data in the file "
                    "(compressed by an extension such as KHR_draco_mesh_compression, or "
                    "sparse), which is not read; export the model uncompressed", path=path)
            n = accessors[pos][0]
            for name, a in refs.items():
                if accessors[a][0] != n:
                    raise FileFormatError(
                        f"glTF {where}: attribute {name} (accessor {a}) holds "
                        f"{accessors[a][0]:,} elements, POSITION holds {n:,}; the file is "
                        "damaged", path=path)
            if "material" in prim:
                _ref(prim["material"], _list(doc, "materials", path), f"{where} material", path)
            if "indices" not in prim:
                continue
            i = _ref(prim["indices"], accessors, f"{where} indices", path)
            if accessors[i][2] not in _INDEX_DTYPES or accessors[i][1] != \
                    _COMPONENT_BYTES[accessors[i][2]] or "bufferView" not in accs[i]:
                raise FileFormatError(f"glTF {where}: its indices (accessor {i}) are not "
                                      "unsigned integer scalars stored in the file", path=path)
            if mode == 4 and accessors[i][0] % 3:
                raise FileFormatError(f"glTF {where}: {accessors[i][0]:,} indices do not make "
                                      "whole triangles; the file is damaged", path=path)
            top = int(_index_values(doc, views, buffers, i).max())
            if top >= n:
                raise FileFormatError(
                    f"glTF {where}: its indices (accessor {i}) refer to vertex {top:,}, the "
                    f"positions (accessor {pos}) hold {n:,}; the file is damaged", path=path)


def _base_colour_images(doc, path):
    """The image indices the materials use as base-colour textures, in order."""
    textures = _list(doc, "textures", path)
    images = _list(doc, "images", path)
    used = []
    for k, mat in enumerate(_list(doc, "materials", path)):
        pbr = mat.get("pbrMetallicRoughness")
        ref = pbr.get("baseColorTexture") if isinstance(pbr, dict) else None
        if not isinstance(ref, dict):
            continue
        t = _ref(ref.get("index"), textures, f"material {k} baseColorTexture", path)
        if "source" not in textures[t]:
            continue
        img = _ref(textures[t]["source"], images, f"texture {t} source", path)
        if img not in used:
            used.append(img)
    return used


def _check_images(doc, views, buffers, path, allow_outside):
    """Check the header of each base-colour image (format, size) as an OBJ's texture is
    checked; return the file names to withhold from trimesh (outside the folder, with a
    warning). KTX2 images, which trimesh does not decode, are named in a warning."""
    skipped = set()
    images = doc.get("images", [])
    folder = path.parent.resolve()
    for k in _base_colour_images(doc, path):
        img = images[k]
        where = f" (image {k})"
        uri = img.get("uri")
        if img.get("mimeType") == "image/ktx2":
            warnings.warn(f"{path}: texture image {k} is KTX2, which is not read; the model is "
                          "read without its texture", UserWarning, stacklevel=3)
            continue
        if "bufferView" in img:
            b, start, length, _ = views[_ref(img["bufferView"], views, f"image {k} bufferView",
                                             path)]
            check_texture(buffers[b].read(start, length), path, where)
        elif isinstance(uri, str) and _inline(uri):
            check_texture(_data_uri(uri, f"image {k}", path), path, where)
        elif isinstance(uri, str):
            target = _uri_target(path.parent, uri)
            if not allow_outside and not target.resolve().is_relative_to(folder):
                warnings.warn(
                    f"{path}: texture {uri}{where} lies outside the model's folder; skipped, "
                    "the model is read without its texture (allow it with "
                    "allow_outside_textures=True, --allow-outside-textures)",
                    UserWarning, stacklevel=3)
                skipped.add(target)
                continue
            if not target.is_file():
                what = "is not a regular file" if target.exists() else "not found"
                raise FileFormatError(f"texture image {uri} {what}{where}", path=path)
            check_texture(target, path, f" ({uri}, image {k})")
        else:
            raise FileFormatError(f"glTF image {k} has neither a bufferView nor a uri",
                                  path=path)
    return skipped


def check_gltf(path: Path, allow_outside: bool = False) -> set:
    """Check a glTF or GLB file before trimesh reads it.

    Buffers must hold their ``byteLength`` (a ``.gltf``'s buffer files lie in its folder
    unless ``allow_outside``), buffer views lie within their buffer, accessors within their
    view (accessors without data stay within the file's size), the attributes of a primitive
    have as many elements as its positions, and its indices name existing vertices. The
    base-colour images are checked from their headers (:func:`~surfidx.io.texture.check_texture`);
    one outside the folder is skipped with a warning unless ``allow_outside``.

    Parameters
    ----------
    path : pathlib.Path
    allow_outside : bool

    Returns
    -------
    set of pathlib.Path
        Image files to withhold from trimesh (skipped with a warning).

    Raises
    ------
    FileFormatError
        Naming the file and the first inconsistency found.
    """
    size = path.stat().st_size
    if path.suffix.lower() == ".glb":
        doc, binary = _glb_layout(path, size)
    else:
        try:
            with open(path, "rb") as fh:
                doc, binary = _parse_json(fh.read(), path), None
        except OSError as exc:
            raise FileFormatError(f"cannot read ({exc.strerror or exc})", path=path) from None
    buffers = _buffers(doc, path, binary, allow_outside)
    views = _views(doc, buffers, path)
    accessors = _accessors(doc, views, size + sum(b.size for b in buffers), path)
    _check_primitives(doc, accessors, views, buffers, path)
    return _check_images(doc, views, buffers, path, allow_outside)


def _resolver(path: Path, allow_outside: bool, skipped: set):
    """A trimesh resolver that reads exactly the file a URI names (no fallback to another
    name), a regular file, inside the model's folder unless ``allow_outside``, and none of
    ``skipped``."""
    import trimesh

    folder = path.parent.resolve()

    class Resolver(trimesh.resolvers.FilePathResolver):
        def get(self, name):
            target = _uri_target(path.parent, name)
            if target in skipped or not target.is_file() or \
                    (not allow_outside and not target.resolve().is_relative_to(folder)):
                raise FileNotFoundError(name)
            return target.read_bytes()

    return Resolver(str(path), allow_anywhere=allow_outside)


def _glb_bytes(positions, normals, colors, faces) -> bytes:
    import trimesh

    if colors is not None:
        colors = np.hstack([colors, np.full((len(colors), 1), 255, np.uint8)])
    if faces is not None and len(faces):
        tm = trimesh.Trimesh(positions, faces, vertex_colors=colors, process=False)
        tm.vertex_normals = normals    # ours, set last: the constructor's caching may drop them
        return tm.export(file_type="glb", include_normals=True)
    return trimesh.PointCloud(positions, colors=colors).export(file_type="glb")


def textured_arrays(model):
    """A textured mesh's arrays split at its texture seams, as GLB (one index per corner) needs
    them: one vertex per distinct (vertex, texture coordinate) pair of the faces, in order of
    first use.

    Parameters
    ----------
    model : TriangleMesh
        With ``uv``, ``uv_faces`` and ``texture``.

    Returns
    -------
    positions : (k, 3) float64
    normals : (k, 3) float64
        The mesh's unit vertex normals.
    uv : (k, 2) float64
        v upwards, as :attr:`surfidx.TriangleMesh.uv`.
    faces : (m, 3) int64
    """
    # model_arrays' vertex colours (the texture sampled at each vertex) are not needed here
    positions, normals, faces = model.vertices, model.vertex_normals(), model.faces
    v, t, corner = _first_use_pairs(faces.ravel(), model.uv_faces.ravel(), len(model.uv))
    return positions[v], normals[v], model.uv[t], corner.reshape(-1, 3)


def _first_use_pairs(v, t, n_uv: int):
    """The distinct pairs ``(v[c], t[c])`` in order of first use, and each corner's pair.

    Most texture coordinates belong to one vertex, so the pairs are found per texture
    coordinate (its first corner's vertex, a table of ``n_uv`` rows) and only the corners
    whose vertex differs from it (a seam shared by several vertices) are sorted.

    Returns
    -------
    pv, pt : (k,) int64
        The pairs' vertex and texture coordinate, in order of first use.
    corner : (len(v),) int64
        Each corner's pair.
    """
    c = np.arange(len(t), dtype=np.int64)
    first = np.full(n_uv, len(t), np.int64)
    np.minimum.at(first, t, c)                 # each texture coordinate's first corner
    used = np.flatnonzero(first < len(t))
    owner = np.full(n_uv, -1, np.int64)
    owner[used] = v[first[used]]
    other = np.flatnonzero(v != owner[t])      # corners whose pair is not their t's first
    key = v[other] * np.int64(n_uv) + t[other]
    _, ofirst, oinv = np.unique(key, return_index=True, return_inverse=True)
    # all pairs by their first corner: one per used texture coordinate, then the others
    start = np.concatenate([first[used], other[ofirst]])
    order = np.argsort(start, kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    slot = np.full(n_uv, -1, np.int64)
    slot[used] = np.arange(len(used))
    corner = rank[slot[t]]
    corner[other] = rank[len(used) + np.asarray(oinv).ravel()]
    pv = np.concatenate([owner[used], key[ofirst] // n_uv])[order]
    pt = np.concatenate([used, key[ofirst] % n_uv])[order]
    return pv, pt, corner


def _textured_glb_bytes(model, image: bytes, image_format: str) -> bytes:
    """GLB of a textured mesh: ``POSITION``, ``NORMAL``, ``TEXCOORD_0`` (glTF's v downwards)
    and indices, and a material whose ``baseColorTexture`` is ``image`` (in the binary chunk;
    WebP through ``EXT_texture_webp``). The sampler filters linearly without mipmaps and
    clamps, so no look-up reads past a chart's gutter."""
    from .texture import IMAGE_FORMATS

    pos, nrm, uv, faces = textured_arrays(model)
    pos = pos.astype("<f4")
    nrm = nrm.astype("<f4")
    tex = np.stack([uv[:, 0], 1.0 - uv[:, 1]], 1).astype("<f4")
    idx = faces.astype("<u4").ravel()
    blobs, views, accessors = [], [], []
    offset = 0

    def add(data: bytes, target=None):
        nonlocal offset
        view = {"buffer": 0, "byteOffset": offset, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        views.append(view)
        blobs.append(data + b"\0" * (-len(data) % 4))
        offset += len(blobs[-1])
        return len(views) - 1

    def accessor(arr, kind, ctype, target, bounds=False):
        acc = {"bufferView": add(arr.tobytes(), target), "componentType": ctype,
               "count": int(len(arr)), "type": kind}
        if bounds:
            acc["min"] = [float(x) for x in arr.min(axis=0)]
            acc["max"] = [float(x) for x in arr.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    a_pos = accessor(pos, "VEC3", 5126, 34962, bounds=True)
    a_nrm = accessor(nrm, "VEC3", 5126, 34962)
    a_tex = accessor(tex, "VEC2", 5126, 34962)
    a_idx = accessor(idx, "SCALAR", 5125, 34963)
    v_img = add(image)
    mime = IMAGE_FORMATS[image_format][1]
    texture = {"sampler": 0, "source": 0}
    doc = {
        "asset": {"version": "2.0", "generator": "surfidx"},
        "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, **({"name": model.name} if model.name else {})}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": a_pos, "NORMAL": a_nrm,
                                                   "TEXCOORD_0": a_tex},
                                    "indices": a_idx, "material": 0, "mode": 4}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                "metallicFactor": 0.0,
                                                "roughnessFactor": 1.0}}],
        "samplers": [{"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}],
        "images": [{"bufferView": v_img, "mimeType": mime}],
        "textures": [texture],
        "accessors": accessors, "bufferViews": views,
        "buffers": [{"byteLength": offset}],
    }
    if image_format == "webp":
        del texture["source"]
        texture["extensions"] = {"EXT_texture_webp": {"source": 0}}
        doc["extensionsUsed"] = doc["extensionsRequired"] = ["EXT_texture_webp"]
    text = json.dumps(doc, separators=(",", ":"), sort_keys=True).encode("utf-8")
    text += b" " * (-len(text) % 4)
    binary = b"".join(blobs)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (_GLB_MAGIC + struct.pack("<II", 2, total)
            + struct.pack("<II", len(text), _CHUNK_JSON) + text
            + struct.pack("<II", len(binary), _CHUNK_BIN) + binary)


def write_glb(model, path, *, text: bool = False, image_format: str = "png",
              image_quality: int | None = None) -> None:
    """Write a model as GLB. A mesh with a texture (``uv``, ``uv_faces``, ``texture``): its
    primitive holds ``POSITION``, ``NORMAL``, ``TEXCOORD_0`` and indices over the vertices split
    at the texture seams (:func:`textured_arrays`), with a material whose ``baseColorTexture``
    is the image (PNG, JPEG, or WebP with ``EXT_texture_webp``). Otherwise (through trimesh) a
    mesh whose primitive holds ``POSITION``, ``NORMAL`` (unit, float32, per vertex:
    :func:`~surfidx.io.arrays.model_arrays`) and ``COLOR_0`` when it has colours, or a point
    cloud for surfels without faces.

    Parameters
    ----------
    model : SurfelSet or TriangleMesh
    path : str or os.PathLike
    text : bool
        Ignored (GLB is binary).
    image_format : {"png", "jpeg", "webp"}
        The texture image's format (a textured mesh only).
    image_quality : int, optional
        JPEG or WebP quality, 1 … 100 (:func:`~surfidx.io.texture.check_image_options`).
    """
    from .texture import check_image_options, encode_image

    fmt, quality = check_image_options(image_format, image_quality)
    if getattr(model, "texture", None) is not None and model.uv is not None:
        data = _textured_glb_bytes(model, encode_image(model.texture, image_format=fmt,
                                                       image_quality=quality), fmt)
    else:
        data = _glb_bytes(*model_arrays(model))
    write_atomic(path, lambda tmp: tmp.write_bytes(data))


def referenced_uris(path) -> list:
    """The relative URIs a glTF or GLB file names for its buffers and images (data URIs left
    out), percent-escapes decoded, in the file's order: the files it needs beside it.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    list of str

    Raises
    ------
    FileFormatError
        Not a readable glTF or GLB file.
    """
    path = Path(path)
    if path.suffix.lower() == ".glb":
        doc, _ = _glb_layout(path, path.stat().st_size)
    else:
        from .files import read_regular

        doc = _parse_json(read_regular(path), path)
    out = []
    for key in ("buffers", "images"):
        for item in _list(doc, key, path):
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and uri and not _inline(uri) and not uri.startswith("data:"):
                out.append(urllib.parse.unquote(uri))
    return list(dict.fromkeys(out))
