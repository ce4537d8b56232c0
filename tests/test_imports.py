"""The package's modules import each other without a circle (imports inside functions too)."""

import ast

from conftest import REPO

PACKAGES = ("surfidx", "ingest")


def _modules():
    """Module name -> source path of every module of :data:`PACKAGES`."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((REPO / pkg).rglob("*.py")):
            parts = list(path.relative_to(REPO).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def _imports(name, path, modules):
    """The modules of the packages that module ``name`` imports, anywhere in its source."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                base = ".".join(base + ([node.module] if node.module else []))
            else:
                base = node.module
            # ``from pkg import sub`` imports the submodule when there is one, else a name of pkg
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                       for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in modules:        # ``import surfidx.sphere.proxy as p``: longest
                t = t.rpartition(".")[0]         # known prefix
            if t and t != name:
                found.add(t)
    return found


def _graph():
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _cycles(graph):
    """Strongly connected components of more than one module (Tarjan), as frozensets."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(frozenset(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_graph_sees_the_imports():
    """The graph finds module-level, relative, aliased and function-level imports."""
    graph = _graph()
    assert "surfidx.geometry.unitsphere" in graph["surfidx.codec.resample"]           # module level, relative
    assert "surfidx.sphere.options" in graph["surfidx.codec.encoder"]  # aliased
    assert "surfidx.codec" in graph["surfidx.pipeline"]               # inside a function
    assert "surfidx.sphere.options" in graph["surfidx.sphere.tutte"]
    assert "surfidx.sphere" in graph["surfidx.cli.sphere"]


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [frozenset("abc")]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_sphere_stage_has_no_import_cycle():
    """The spherical map, the sphere geometry, the resampling and the grid: acyclic."""
    own = ("surfidx.sphere", "surfidx.geometry.unitsphere", "surfidx.codec.resample", "surfidx.geometry.icosphere")
    graph = _graph()
    sub = {v: {w for w in ws if w.startswith(own)} for v, ws in graph.items()
           if v.startswith(own)}
    assert "surfidx.sphere.tutte" in sub
    cycles = _cycles(sub)
    assert not cycles, f"import cycles: {[sorted(c) for c in cycles]}"


def test_no_import_cycle_at_all():
    """No module of the packages imports, directly or through others, a module that imports it."""
    cycles = _cycles(_graph())
    assert not cycles, f"import cycles: {[sorted(c) for c in cycles]}"


def test_the_command_modules_import_the_group_not_the_package():
    """The click group lives in ``cli/group.py``; the package imports the command modules."""
    graph = _graph()
    for m in ("codec", "convert", "db", "geodesic", "sphere", "view"):
        assert "surfidx.cli.group" in graph[f"surfidx.cli.{m}"]
        assert "surfidx.cli" not in graph[f"surfidx.cli.{m}"]
        assert f"surfidx.cli.{m}" in graph["surfidx.cli"]


def _lazy_packages():
    """Package name -> the names its ``__init__.pyi`` exports and the submodules they come from."""
    out = {}
    for stub in sorted((REPO / "surfidx").rglob("__init__.pyi")):
        parts = list(stub.parent.relative_to(REPO).parts)
        exports = {}
        for node in ast.parse(stub.read_text()).body:
            if isinstance(node, ast.ImportFrom):
                for a in node.names:
                    exports[a.asname or a.name] = node.module
        out[".".join(parts)] = exports
    return out


def test_no_lazy_export_is_shadowed_by_its_submodule():
    """An export named as a submodule would turn into the module once that is imported."""
    import importlib
    import pkgutil

    packages = _lazy_packages()
    assert {"surfidx", "surfidx.codec", "surfidx.sphere", "surfidx.db"} <= set(packages)
    for package, exports in packages.items():
        pkg = importlib.import_module(package)
        submodules = {m.name for m in pkgutil.iter_modules(pkg.__path__)}
        for name, module in exports.items():
            assert name not in submodules, f"{package}.{name} is also a submodule"
            source = importlib.import_module(f"{package}.{module}")
            assert getattr(pkg, name) is getattr(source, name), f"{package}.{name}"
        assert set(exports) <= set(pkg.__all__) and set(exports) <= set(dir(pkg))


# -- private names stay inside their package ------------------------------------------------------

# a private name (``_x``, not a dunder) of a module is used only by the modules of its own package
# (``surfidx.codec``, ``surfidx.geometry``, ..., ``surfidx`` for the top-level modules,
# ``ingest``); the tests are a package of their own and import from ``conftest`` and ``helpers``
ALLOWED_PRIVATE: set[str] = set()


def _private(name):
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _package_of(module, path):
    """The package that owns the private names of ``module`` (its own name for an ``__init__``)."""
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def _owner(dotted, modules):
    """The package owning the private last part of ``dotted`` (``pkg.mod._x`` -> ``pkg``)."""
    parent = dotted.rpartition(".")[0]
    if parent in modules and modules[parent].name == "__init__.py":
        return parent                            # a name or submodule of a package
    return parent.rpartition(".")[0]             # a name of a module


def _crossings(module, path, package, modules):
    """``(line, dotted name)`` of each private name of another package that ``module`` uses."""
    tree = ast.parse(path.read_text(), str(path))
    bound = {}                                   # local name -> module it stands for
    found = []

    def check(dotted, line):
        """Every private part of ``dotted`` (a path through known modules) must be ours."""
        parts = dotted.split(".")
        for i in range(1, len(parts)):
            if _private(parts[i]) and ".".join(parts[:i]) in modules:
                full = ".".join(parts[:i + 1])
                if _owner(full, modules) != package and full not in ALLOWED_PRIVATE:
                    found.append((line, full))
                if full not in modules:
                    break

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                check(a.name, node.lineno)
                if a.asname:
                    bound[a.asname] = a.name
                else:
                    bound[a.name.split(".")[0]] = a.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
                base = base[:len(base) - node.level + 1]
                base = ".".join(base + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            for a in node.names:
                check(f"{base}.{a.name}", node.lineno)
                if f"{base}.{a.name}" in modules:
                    bound[a.asname or a.name] = f"{base}.{a.name}"
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            chain = []
            cur = node
            while isinstance(cur, ast.Attribute):
                chain.append(cur.attr)
                cur = cur.value
            if isinstance(cur, ast.Name) and cur.id in bound and bound[cur.id] in modules:
                check(".".join([bound[cur.id], *reversed(chain)]), node.lineno)
    return found


def _all_crossings():
    modules = _modules()
    out = []
    for name, path in modules.items():
        out += [(f"{path.relative_to(REPO)}:{line}", full)
                for line, full in _crossings(name, path, _package_of(name, path), modules)]
    for path in sorted((REPO / "tests").glob("*.py")):
        out += [(f"{path.relative_to(REPO)}:{line}", full)
                for line, full in _crossings(f"tests.{path.stem}", path, "tests", modules)]
    return sorted(set(out))


def test_the_scan_sees_private_names_across_packages(tmp_path):
    """``from``-imports, module attributes through aliases and private modules are all seen; the
    module's own package may use its private names."""
    modules = _modules()
    src = tmp_path / "x.py"
    src.write_text("from surfidx.geometry.icosphere import _a, b\n"
                   "import surfidx.sphere.balance as bal\n"
                   "from surfidx.db import catalog\n"
                   "import ingest._run\n"
                   "def f():\n"
                   "    return bal._b, catalog.c, catalog._d, bal.x._y\n")
    found = {full for _, full in _crossings("surfidx.codec.x", src, "surfidx.codec", modules)}
    assert found == {"surfidx.geometry.icosphere._a", "surfidx.sphere.balance._b",
                     "surfidx.db.catalog._d", "ingest._run"}
    assert _crossings("surfidx.geometry.x", src, "surfidx.geometry", modules) != []
    mine = {full for _, full in _crossings("surfidx.geometry.x", src, "surfidx.geometry", modules)}
    assert "surfidx.geometry.icosphere._a" not in mine


def test_no_private_name_crosses_a_package_boundary():
    """No module uses a private name (``_x``) of a module of another package."""
    crossings = _all_crossings()
    assert not crossings, "private names used across packages:\n" + "\n".join(
        f"  {where}: {full}" for where, full in crossings)


def test_test_files_share_helpers_only_through_conftest_and_helpers():
    """A test file imports no other test file: shared helpers live in ``helpers.py``."""
    tests = {p.stem for p in (REPO / "tests").glob("*.py")} - {"conftest", "helpers"}
    found = []
    for path in sorted((REPO / "tests").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module] if isinstance(node, ast.ImportFrom) and not node.level
                     else [])
            found += [f"{path.name}:{node.lineno}: {n}" for n in names
                      if n and n.split(".")[0] in tests]
    assert not found, "test files importing test files:\n" + "\n".join(found)


def test_describing_a_mesh_file_loads_only_the_modules_it_uses(tmp_path):
    """A query by an OFF mesh (:func:`surfidx.pipeline.describe_model`) imports neither the
    other formats' readers, nor the point-cloud code (normals, proxy surface, scipy.ndimage), nor
    the MDS map, nor the renderer; ``surfidx info`` of it (closed: no boundary to trace, no
    handle to cut) neither scipy.spatial nor numba."""
    import json
    import subprocess
    import sys

    from helpers import off_sphere

    path = tmp_path / "ball.off"
    path.write_text(off_sphere("OFF\n{nv} {nf} 0"))
    unused = ["surfidx.io.gltf", "surfidx.io.las", "surfidx.io.e57", "surfidx.io.obj",
              "surfidx.io.pcd", "surfidx.geometry.pointcloud", "surfidx.sphere.cloud",
              "surfidx.sphere.proxy", "surfidx.sphere.mds", "surfidx.render", "scipy.ndimage"]
    code = ("import sys, json\n"
            "from surfidx.pipeline import describe_model\n"
            f"describe_model({str(path)!r})\n"
            f"print(json.dumps(sorted(set({unused!r}) & set(sys.modules))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=600, check=True).stdout
    assert json.loads(out.splitlines()[-1]) == []
    code = ("import sys, json\n"
            "from surfidx.cli import cli\n"
            f"cli.main(['info', {str(path)!r}], standalone_mode=False)\n"
            f"print(json.dumps(sorted(set({unused + ['scipy.spatial', 'numba']!r}) "
            "& set(sys.modules))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=600, check=True).stdout
    assert json.loads(out.splitlines()[-1]) == []
