"""Sphinx extension of the surfidx docs: the API pages from the packages' public names.

``.. public-api:: surfidx.geometry`` documents every name of the module's ``__all__`` (for a
lazy package, the names its ``__init__.pyi`` stub lists) with autodoc, once: a name several
packages offer (``surfidx.SurfelSet`` is ``surfidx.geometry.SurfelSet``) is documented on the
page of the package that defines it, and listed with a link on the others. So a new public name
appears in the reference by itself, and an API page is a file with one directive.

The build fails (``-W``) on

- a public name, or a public method or property of a public class, without a docstring;
- a cross-reference (``:func:``, ``:class:``, ...) to something that does not exist.

A reference by another path to a documented object (``surfidx.SurfelSet``,
``surfidx.geometry.surfels.SurfelSet``, a method through either) is sent to the documented one;
a reference to an existing object the reference does not document (a private helper named for
contributors) is shown as code, without a link.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import inspect
import pkgutil
import re
from pathlib import Path

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.pycode import ModuleAnalyzer
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

logger = logging.getLogger(__name__)

DIRECTIVE = re.compile(r"^\s*(?:\.\. |```\{)public-api(?::: |\}\s*)([\w.]+)", re.M)
MAX_VALUE = 70
PROJECT = ("surfidx", "ingest")


# ---------------------------------------------------------------- the public names and owners
def public_names(modname: str) -> list[str]:
    """The names of a module's ``__all__``, without dunder names (``__version__``)."""
    module = importlib.import_module(modname)
    return [n for n in getattr(module, "__all__", []) if not n.startswith("__")]


def stub_sources(modname: str) -> dict[str, str]:
    """Name -> the module a lazy package's ``__init__.pyi`` imports it from."""
    module = importlib.import_module(modname)
    stub = Path(module.__file__).with_suffix(".pyi")
    sources = {}
    if stub.name == "__init__.pyi" and stub.exists():
        for node in ast.walk(ast.parse(stub.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = importlib.util.resolve_name("." * node.level + (node.module or ""),
                                                   modname)  # the stub is the package's
                for alias in node.names:
                    sources[alias.asname or alias.name] = base
    return sources


def defining_module(modname: str, name: str, obj) -> str:
    """The module that defines ``modname.name``."""
    owner = getattr(obj, "__module__", None)
    if isinstance(owner, str) and (inspect.isclass(obj) or callable(obj)):
        return owner
    return stub_sources(modname).get(name, modname)


def build_registry(app) -> None:
    """Find the API modules (the ``public-api`` directives of the sources) and decide where each
    public object is documented: in the API module that defines it (the longest prefix of its
    defining module), else the first that offers it."""
    srcdir = Path(app.srcdir)
    modules = []
    for path in sorted(srcdir.rglob("*")):
        if path.suffix in (".rst", ".md") and "_build" not in path.parts:
            modules += DIRECTIVE.findall(path.read_text(encoding="utf-8"))
    offers: dict[str, list[str]] = {}        # defining path -> API modules offering it
    objects: dict[str, object] = {}
    for modname in modules:
        module = importlib.import_module(modname)
        for name in public_names(modname):
            obj = getattr(module, name)
            real = f"{defining_module(modname, name, obj)}.{name}"
            if inspect.isclass(obj) or inspect.isfunction(obj):
                real = f"{obj.__module__}.{obj.__qualname__}"
            offers.setdefault(real, []).append(modname)
            objects[real] = obj
    owner, alias = {}, {}
    for real, mods in offers.items():
        inside = [m for m in mods if real == m or real.startswith(m + ".")]
        home = max(inside, key=len) if inside else mods[0]
        documented = f"{home}.{real.rsplit('.', 1)[1]}"
        for m in mods:
            owner[(m, real.rsplit(".", 1)[1])] = home
            alias[f"{m}.{real.rsplit('.', 1)[1]}"] = documented
        alias[real] = documented
    app.env.surfidx_api_modules = modules
    app.env.surfidx_api_owner = owner
    app.env.surfidx_api_alias = alias


# ---------------------------------------------------------------------------- the directive
class PublicAPI(SphinxDirective):
    """``.. public-api:: MODULE``: the module's docstring, then each public name it owns."""

    required_arguments = 1

    def run(self):
        modname = self.arguments[0]
        module = importlib.import_module(modname)
        owner = self.env.surfidx_api_owner
        lines = [f".. automodule:: {modname}", "   :no-members:", ""]
        elsewhere = []
        for name in public_names(modname):
            obj = getattr(module, name)
            home = owner.get((modname, name), modname)
            if home != modname:
                elsewhere.append((name, home))
                continue
            lines += self.entry(modname, name, obj)
        if elsewhere:
            refs = ", ".join(f":py:obj:`{name} <{home}.{name}>`" for name, home in elsewhere)
            lines += ["", f"Also offered here, documented with the package that defines them: "
                          f"{refs}.", ""]
        content = nodes.section()
        nested_parse_with_titles(self.state, StringList(lines, source=self.get_source_info()[0]),
                                 content)
        return content.children

    def entry(self, modname, name, obj):
        full = f"{modname}.{name}"
        if inspect.isclass(obj):
            if not inspect.getdoc(obj) or obj.__doc__ is None:
                self.missing(full)
            kind = "autoexception" if issubclass(obj, BaseException) else "autoclass"
            # members inherited from the project's own classes (Database from Catalog) are
            # the class's API; those of outside bases (Exception, tuple, dict) are not
            outside = sorted({base.__name__ for base in obj.__mro__[1:]
                              if base.__module__.split(".")[0] not in PROJECT})
            bases = ["   :show-inheritance:"] if obj.__bases__ != (object,) else []
            return [f".. {kind}:: {full}", "   :members:", *bases,
                    f"   :inherited-members: {', '.join(outside)}", ""]
        if callable(obj):
            if not getattr(obj, "__doc__", None):
                self.missing(full)
            return [f".. autofunction:: {full}", ""]
        # a constant: its docstring is the string (or ``#:`` comment) beside its assignment
        doc = attribute_doc(defining_module(modname, name, obj), name)
        if not doc:
            self.missing(full)
            doc = []
        value = object_value(obj)
        head = [f".. py:data:: {name}", f"   :module: {modname}"]
        if value is not None:
            head.append(f"   :value: {value}")
        return head + [""] + [f"   {line}" for line in doc] + [""]

    def missing(self, full):
        logger.warning(f"public name {full} has no docstring", location=self.get_location())


def attribute_doc(modname: str, name: str, depth: int = 0) -> list[str]:
    """The docstring of module constant ``modname.name``, following ``from x import name``."""
    try:
        doc = ModuleAnalyzer.for_module(modname).find_attr_docs().get(("", name))
    except Exception:                                            # noqa: BLE001 - no source
        return []
    if doc or depth > 5:
        return list(doc or [])
    module = importlib.import_module(modname)
    package = modname if Path(module.__file__).stem == "__init__" else modname.rpartition(".")[0]
    for node in ast.walk(ast.parse(Path(module.__file__).read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                if (alias.asname or alias.name) == name:
                    source = importlib.util.resolve_name("." * node.level + (node.module or ""),
                                                         package)
                    return attribute_doc(source, alias.name, depth + 1)
    return []


def object_value(obj):
    """A short repr of a constant's value, or None when it would be long."""
    text = repr(obj)
    return text if len(text) <= MAX_VALUE and "\n" not in text else None


# ------------------------------------------------------------------- undocumented members
def skip_member(app, what, name, obj, skip, options):
    """Warn about a public method or property of a documented class without a docstring."""
    if what in ("class", "exception") and skip and not name.startswith("_"):
        target = obj.fget if isinstance(obj, property) else obj
        if (inspect.isfunction(target) or inspect.ismethod(target)
                or isinstance(obj, (classmethod, staticmethod, property))) \
                and not inspect.getdoc(target):
            logger.warning(f"public member {name} of a documented class has no docstring "
                           f"({getattr(target, '__qualname__', name)})")
    return None


# ------------------------------------------------------------------------ references
def find_object(path: str):
    """The object a dotted path names, importing its longest module prefix; None if none."""
    parts = path.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        except Exception:                                        # noqa: BLE001 - any import
            return None
        try:
            for attr in parts[cut:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return None
        return obj
    return None


def init_parameters(cls) -> set[str]:
    """The parameter names of a class's constructor."""
    try:
        return set(inspect.signature(cls).parameters)
    except (TypeError, ValueError):
        return set()


def missing_reference(app, env, node, contnode):
    """Send a reference to the documented object, or show an existing undocumented one as code."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip("~.")
    domain = env.get_domain("py")
    candidates = [target]
    for context in (node.get("py:class"), node.get("py:module")):
        if context:
            candidates.insert(0, f"{context}.{target}")
    # the module and class of the docstring the reference is in (its own short names)
    where = re.search(r"docstring of ([\w.]+)", str(node.source or ""))
    if where:
        path = where.group(1)
        while path:
            obj = find_object(path)
            if inspect.ismodule(obj):
                candidates.insert(0, f"{path}.{target}")
                # a name of a sibling module (``AnnIndex`` of ``surfidx.db.ann`` in
                # ``surfidx.db.search``), tried last
                package = importlib.import_module(path.rpartition(".")[0] or path)
                for sub in pkgutil.iter_modules(getattr(package, "__path__", [])):
                    candidates.append(f"{package.__name__}.{sub.name}.{target}")
                break
            if inspect.isclass(obj):
                candidates.insert(0, f"{path}.{target}")
            path = path.rpartition(".")[0]
    module = node.get("py:module") or ""
    while module:
        candidates.append(f"{module}.{target}")
        module = module.rpartition(".")[0]
    alias = env.surfidx_api_alias
    for candidate in candidates:
        parts = candidate.split(".")
        for cut in range(len(parts), 0, -1):
            head = ".".join(parts[:cut])
            if head in alias:
                resolved = ".".join([alias[head], *parts[cut:]])
                if resolved in domain.objects or resolved in domain.modules:
                    return domain.resolve_xref(env, node["refdoc"], app.builder,
                                               node["reftype"], resolved, node, contnode)
    # a module below a documented one (``surfidx.geometry.surfels``): its package's page
    if node["reftype"] == "mod":
        for candidate in candidates:
            if find_object(candidate) is not None:
                package = candidate
                while package and package not in domain.modules:
                    package = package.rpartition(".")[0]
                if package:
                    return domain.resolve_xref(env, node["refdoc"], app.builder, "mod", package,
                                               node, contnode)
    # a unique documented object whose name ends so (``SurfelSet.patch`` from another module)
    # (among several, the one in the module the reference is made from)
    ends = [name for name in domain.objects if name.endswith("." + target)]
    here = [name for name in ends if node.get("py:module")
            and name.startswith(node["py:module"] + ".")]
    for found in (ends, here):
        if len(found) == 1:
            return domain.resolve_xref(env, node["refdoc"], app.builder, node["reftype"],
                                       found[0], node, contnode)
    # an attribute a class sets from its parameter of that name (documented with the parameters)
    if node["reftype"] == "attr":
        for candidate in candidates:
            owner, _, attr = candidate.rpartition(".")
            cls = find_object(owner) if owner else None
            if inspect.isclass(cls) and attr in init_parameters(cls):
                return contnode
    for candidate in [*candidates, f"builtins.{target}"]:
        if find_object(candidate) is not None:
            return contnode                                     # real, just not in the reference
    if target.split(".")[0] in app.config.surfidx_external_roots:
        return contnode
    return None


def setup(app):
    app.add_config_value("surfidx_external_roots", (), "env")
    app.add_directive("public-api", PublicAPI)
    app.connect("builder-inited", build_registry)
    app.connect("autodoc-skip-member", skip_member)
    app.connect("missing-reference", missing_reference, priority=900)
    return {"version": "1", "parallel_read_safe": False, "parallel_write_safe": True}
