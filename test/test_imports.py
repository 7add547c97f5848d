"""No import circles inside the package: the graph of its module-level imports
has no cycle, and every module imports alone, with none of the package loaded
before it."""
import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("skin_node", "msg_adapters")


def modules() -> dict:
    """Every module of the packages: dotted name -> (file, is a package)."""
    out = {}
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(f.relative_to(ROOT).with_suffix("").parts)
            is_pkg = parts[-1] == "__init__"
            out[".".join(parts[:-1] if is_pkg else parts)] = (f, is_pkg)
    return out


def _executed_imports(tree: ast.Module):
    """The import statements that run when the module is imported: those of its
    body and of the blocks and class bodies in it, not those inside functions."""
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            stack.extend(c for c in ast.iter_child_nodes(node)
                         if isinstance(c, (ast.stmt, ast.excepthandler)))


def import_graph(inside_functions: bool = False) -> dict:
    """module -> the modules of the packages its module-level imports run
    (with ``inside_functions``, those its functions import too).

    ``from pkg import name`` counts ``pkg.name`` when that is a module; importing
    ``a.b.c`` runs ``a`` and ``a.b`` first, so those count too, but for the
    packages that hold the importing module (already running when it runs)."""
    mods = modules()
    graph = {}
    for name, (path, is_pkg) in mods.items():
        here = name.split(".") if is_pkg else name.split(".")[:-1]
        deps = set()
        tree = ast.parse(path.read_text(), str(path))
        found = (n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))) \
            if inside_functions else _executed_imports(tree)
        for node in found:
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                base = here[:len(here) - node.level + 1] if node.level else []
                target = ".".join(base + ([node.module] if node.module else []))
                targets = [target] + [f"{target}.{a.name}" for a in node.names
                                      if f"{target}.{a.name}" in mods]
            for t in targets:
                parts = t.split(".")
                for k in range(1, len(parts) + 1):
                    dep = ".".join(parts[:k])
                    if dep in mods and dep != name and not name.startswith(dep + "."):
                        deps.add(dep)
        graph[name] = deps
    return graph


def find_cycle(graph: dict) -> list | None:
    """One cycle of ``graph`` as ``[a, b, ..., a]``, or None."""
    state = dict.fromkeys(graph, 0)         # 0 unseen, 1 on the path, 2 done
    path: list = []

    def visit(v):
        state[v] = 1
        path.append(v)
        for w in sorted(graph[v]):
            if state[w] == 1:
                return path[path.index(w):] + [w]
            if state[w] == 0:
                found = visit(w)
                if found:
                    return found
        path.pop()
        state[v] = 2
        return None

    for v in sorted(graph):
        if state[v] == 0:
            found = visit(v)
            if found:
                return found
    return None


def test_the_graph_of_module_level_imports_has_no_cycle():
    graph = import_graph()
    assert len(graph) > 50 and "skin_node.node" in graph and "msg_adapters" in graph
    cycle = find_cycle(graph)
    assert cycle is None, "import circle: " + " -> ".join(cycle)


def test_no_circle_hides_behind_an_import_inside_a_function():
    """An import moved into a function dodges a circle at import time but
    keeps it: the modules still need each other."""
    cycle = find_cycle(import_graph(inside_functions=True))
    assert cycle is None, "import circle through a function: " + " -> ".join(cycle)


def test_a_cycle_is_found_where_there_is_one():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


# Imports each module named on the command line as the first of the packages
# to load: the packages' modules are dropped from sys.modules before each one
# (the third-party ones stay, which keeps it fast).
_IMPORT_EACH = r"""
import importlib, sys, traceback
failed = []
for name in sys.argv[2:]:
    for m in [m for m in sys.modules if m.split(".")[0] in sys.argv[1].split(",")]:
        del sys.modules[m]
    try:
        importlib.import_module(name)
    except BaseException:
        failed.append(f"{name}:\n{traceback.format_exc(limit=-4)}")
print("\n".join(failed))
sys.exit(1 if failed else 0)
"""


def test_every_module_imports_alone_in_a_fresh_interpreter():
    names = sorted(modules())
    batches = [names[k::2] for k in range(2)]          # two processes, side by side
    procs = [subprocess.Popen([sys.executable, "-c", _IMPORT_EACH, ",".join(PACKAGES), *b],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for b in batches]
    failures = [out for p in procs for out in [p.communicate(timeout=120)[0]] if p.returncode]
    assert not failures, "\n".join(failures)
