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
