"""The import graph of engine/ and addon/, read from the source (docs/design.md, Imports).

Every ``import`` / ``from ... import`` at any depth (inside functions too)
is an edge, relative imports resolved; the add-on's string imports
(``backend.load('x')``) and ``backend.engine()`` count as edges into the
engine.  The graph must have no cycle, the engine must not import Blender's
modules, and the add-on reaches the engine only through ``backend.engine()``
and the names ``engine.__all__`` declares.
"""
import ast
import os

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PACKAGES = ("engine", "addon")
BLENDER_MODULES = {"bpy", "bpy_extras", "bmesh", "gpu", "gpu_extras", "mathutils", "bl_math",
                   "addon_utils", "aud", "idprop"}


def _sources():
    """{module name: (path, is package)} for every .py file of engine/ and addon/."""
    found = {}
    for package in PACKAGES:
        for folder, dirs, files in os.walk(os.path.join(ROOT, package)):
            dirs[:] = sorted(d for d in dirs if d not in ("__pycache__", "vendor"))
            for name in sorted(files):
                if not name.endswith(".py"):
                    continue
                path = os.path.join(folder, name)
                parts = os.path.relpath(path, ROOT)[:-3].split(os.sep)
                is_package = parts[-1] == "__init__"
                found[".".join(parts[:-1] if is_package else parts)] = (path, is_package)
    return found


SOURCES = _sources()
TREES = {name: ast.parse(open(path, encoding="utf-8").read(), path) for name, (path, _) in SOURCES.items()}


def _project(dotted):
    """The module of the project ``dotted`` names (its longest known prefix), or None."""
    parts = dotted.split(".")
    while parts:
        name = ".".join(parts)
        if name in SOURCES:
            return name
        parts.pop()
    return None


def _base(module, level, target):
    """The absolute name ``from <level dots><target>`` means inside ``module``."""
    if not level:
        return target or ""
    package = module if SOURCES[module][1] else module.rpartition(".")[0]
    for _ in range(level - 1):
        package = package.rpartition(".")[0]
    return f"{package}.{target}" if target else package


def _is_backend_call(node, module, function):
    """``backend.<function>(...)`` (or ``<function>(...)`` inside addon/backend.py)."""
    if not isinstance(node, ast.Call):
        return False
    func = node.func
    if isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name):
        return func.value.id == "backend" and func.attr == function
    return module == "addon.backend" and isinstance(func, ast.Name) and func.id == function


def imports(module):
    """[(imported dotted name, line, how)] of a module: every import statement
    at any depth, relative names resolved (how 'import'), the add-on's string
    imports (``backend.load('x')``: 'string') and ``backend.engine()`` ('door')."""
    out = []
    for node in ast.walk(TREES[module]):
        if isinstance(node, ast.Import):
            out += [(alias.name, node.lineno, "import") for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = _base(module, node.level, node.module)
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                out.append((sub if _project(sub) == sub else base, node.lineno, "import"))
        elif _is_backend_call(node, module, "load") and node.args:
            arg = node.args[0]
            name = arg.value if isinstance(arg, ast.Constant) else "<computed>"
            out.append((f"engine.{name}", node.lineno, "string"))
        elif _is_backend_call(node, module, "engine"):
            out.append(("engine", node.lineno, "door"))
        elif _is_dynamic_import(node) and module != "addon.backend":
            out.append(("<computed>", node.lineno, "string"))
    return out


def _is_dynamic_import(node):
    """``importlib.import_module(...)`` or ``__import__(...)``: only backend may."""
    func = getattr(node, "func", None)
    return isinstance(node, ast.Call) and (
        isinstance(func, ast.Attribute) and func.attr == "import_module"
        or isinstance(func, ast.Name) and func.id in ("__import__", "import_module"))


def _targets(module, name):
    """The project modules importing ``name`` runs from ``module``: its own
    module and the packages above it (``a.b.c`` runs ``a/b/__init__.py``),
    except those above ``module`` itself (already running)."""
    target = _project(name)
    if target is None:
        return set()
    out, parts = {target}, target.split(".")
    mine = module.split(".")
    for i in range(1, len(parts)):
        if parts[:i] != mine[:i]:
            out.add(".".join(parts[:i]))
    return out


def graph():
    """{module: {project modules it imports}} (a module importing itself included)."""
    return {m: set().union(*(_targets(m, name) for name, _, _ in imports(m))) for m in SOURCES}


def cycles(edges):
    """Strongly connected components of more than one module, and self-loops
    (Tarjan's algorithm), each a frozenset."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1 or v in edges.get(v, ()):
                found.append(frozenset(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return found


def _describe(component, edges):
    inner = sorted(f"{a} -> {b}" for a in component for b in edges[a] if b in component)
    return "{" + ", ".join(sorted(component)) + "}: " + "; ".join(inner)


def test_no_import_cycles():
    edges = graph()
    found = set(cycles(edges))
    assert not found, "import cycles:\n" + "\n".join(_describe(c, edges) for c in sorted(found, key=sorted))


def test_engine_does_not_import_blender_or_the_addon():
    bad = [f"{m}:{line} imports {name}" for m in SOURCES if m.split(".")[0] == "engine"
           for name, line, _ in imports(m)
           if name.split(".")[0] in BLENDER_MODULES or name.split(".")[0] == "addon"]
    assert not bad, "\n".join(bad)


def declared_surface():
    """The names of ``engine.__all__``, read from engine/__init__.py."""
    for node in TREES["engine"].body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "__all__" for t in node.targets):
            return set(ast.literal_eval(node.value))
    return set()


def test_addon_reaches_the_engine_only_through_its_surface():
    bad = [f"{m}:{line} imports {name}" for m in SOURCES if m.split(".")[0] == "addon"
           for name, line, how in imports(m) if how == "string" or how == "import" and (
               name.split(".")[0] == "engine" or "vendor" in name.split("."))]
    surface = declared_surface()
    for m in SOURCES:
        if m.split(".")[0] == "addon":
            bad += [f"{m}:{line} uses engine.{attr}, which engine.__all__ does not declare"
                    for attr, line in engine_attributes(m) if attr not in surface]
    assert not bad, "\n".join(bad)


def engine_attributes(module):
    """[(attribute, line)] the module reads from the engine package: on
    ``backend.engine()`` itself, on calls of the module's functions that
    return it (``def _scene(): return backend.engine()``) and on names bound
    to either (``renderer = backend.engine()``)."""
    tree = TREES[module]
    wrappers = {node.name for node in tree.body if isinstance(node, ast.FunctionDef)
                and isinstance(node.body[-1], ast.Return)
                and _is_backend_call(node.body[-1].value, module, "engine")}

    def is_engine(node):
        return _is_backend_call(node, module, "engine") or (
            isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in wrappers)

    bound = {t.id for node in ast.walk(tree) if isinstance(node, ast.Assign) and is_engine(node.value)
             for t in node.targets if isinstance(t, ast.Name)}
    return [(node.attr, node.lineno) for node in ast.walk(tree) if isinstance(node, ast.Attribute)
            and (is_engine(node.value) or isinstance(node.value, ast.Name) and node.value.id in bound)]


def test_the_surface_exists():
    import engine
    assert declared_surface() == set(engine.__all__)
    missing = sorted(name for name in engine.__all__ if not hasattr(engine, name))
    assert not missing, missing


def test_the_graph_sees_what_it_must():
    """The checks above are only as good as the graph: a relative import at
    function depth, a string import and a self-loop must all be edges."""
    source = ("from . import backend\n"
              "def f():\n"
              "    from .export import nodes\n"
              "    return backend.load('scene'), backend.engine().render\n"
              "def _engine():\n"
              "    return backend.engine()\n"
              "renderer = _engine()\n"
              "renderer.Scene, _engine().Mesh\n"
              "importlib.import_module('x')\n")
    TREES["addon.probe_"] = ast.parse(source)
    SOURCES["addon.probe_"] = ("probe_.py", False)
    try:
        found = {(name, how) for name, _, how in imports("addon.probe_")}
        assert found == {("addon.backend", "import"), ("addon.export.nodes", "import"),
                         ("engine.scene", "string"), ("engine", "door"), ("<computed>", "string")}
        assert sorted(engine_attributes("addon.probe_")) == [("Mesh", 8), ("Scene", 8), ("render", 4)]
    finally:
        del TREES["addon.probe_"], SOURCES["addon.probe_"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"d"}, "e": {"a"}}) == \
        [frozenset("abc"), frozenset("d")]


def test_the_addon_version_agrees_with_bl_info():
    """bl_info stays a literal Blender reads without importing the package;
    addon/version.py gives the same number to the modules that record it."""
    bl_info = next(node.value for node in TREES["addon"].body if isinstance(node, ast.Assign)
                   and getattr(node.targets[0], "id", None) == "bl_info")
    version = next(node.value for node in TREES["addon.version"].body if isinstance(node, ast.Assign))
    assert ast.literal_eval(bl_info)["version"] == ast.literal_eval(version)
