"""The package's import graph: no cycles, dependencies pointing down only.

Every module of ``humanoid_reach_ros`` is parsed with ``ast`` (nothing is imported or run),
and every ``import`` / ``from ... import`` in it counts, at module level or inside a
function, absolute or relative. ``from pkg import name`` counts as an import of
``pkg.name`` when that is a module, else of ``pkg``.

The layers, lowest first (``LAYERS``): a module may import modules of its own unit
(sub-package, or top-level module) and of units in lower layers, never of a unit in its own
layer or above. So the core (everything below ``io``) never imports ``io/`` (message
conversion) or ``nodes/``, and ``control/`` never imports ``planning/`` (planning's smooth
reshaping uses control's HQP; what both need, e.g. the spline trajectory, lives in
``geometry/``).
"""
from __future__ import annotations

import ast
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

PKG = "humanoid_reach_ros"
PKG_DIR = Path(__file__).resolve().parents[1] / PKG

#: lowest first; units of one layer do not import each other
LAYERS: list[tuple[str, ...]] = [
    ("", "codes", "paths", "yaml_checks", "params", "counters"),  # "" is the package itself (__version__)
    ("robot",),
    ("kinematics",),                     # limb IK: the solver protocol, registry and solvers
    ("geometry",),
    ("scene",),                          # the planning scene: the one world model
    ("perception", "dual_arm", "sim"),   # sim: the scene description and simulated sensors
    ("control",),                        # the HQP, tasks, limits, the whole-body executor
    ("planning",),                       # smooth reshaping solves with control's HQP
    ("execution",),                      # supervisor and engines around control / reach / planning
    ("operator",),                       # the operator CLI's flow, arguments and reports (no rclpy, io/, nodes/)
    ("io",),                             # numpy <-> ROS messages, MCAP
    ("graph",),                          # process orchestration (the demo's and hr_graph's)
    ("nodes",),                          # thin rclpy nodes (and the executor's loop process)
    ("demo", "warmup", "graph_up"),      # whole-package entry points (graph_up: hr_graph)
    ("testing",),                        # tooling of tests and benches: nothing above imports it
]
RANK = {unit: i for i, layer in enumerate(LAYERS) for unit in layer}
CORE = ("robot", "kinematics", "geometry", "scene", "perception", "dual_arm", "sim", "control", "planning",
        "execution")

#: known cycles, each an import edge (importer, imported) whose removal breaks it (none left: the
#: planning/path <-> rrt_connect / prm cycle went with planning/space.py).
ALLOWED_CYCLE_EDGES: set[tuple[str, str]] = set()   # none: keep it empty


@dataclass(frozen=True)
class Import:
    importer: str
    imported: str
    line: int

    def __str__(self) -> str:
        return f"{self.importer} -> {self.imported} (line {self.line})"


def module_files() -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` of the package."""
    out = {}
    for path in sorted(PKG_DIR.rglob("*.py")):
        parts = list(path.relative_to(PKG_DIR.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _own_module(name: str, modules: dict[str, Path]) -> str | None:
    """The longest prefix of ``name`` that is a module of the package (None: not ours)."""
    while name:
        if name in modules:
            return name
        name = name.rpartition(".")[0]
    return None


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> list[Import]:
    """Every import of a package module in ``path``, at any depth of the syntax tree."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            targets = [f"{stem}.{a.name}" for a in node.names]
        for name in targets:
            own = _own_module(name, modules)
            if own is not None and own != module:
                out.append(Import(module, own, node.lineno))
    return out


def import_graph() -> tuple[dict[str, Path], list[Import]]:
    modules = module_files()
    return modules, [e for m, p in modules.items() for e in imports_of(m, p, modules)]


def unit(module: str) -> str:
    """Sub-package or top-level module a module belongs to ("" for the package itself)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def cycles(edges: list[Import], ignore: set[tuple[str, str]] = frozenset()) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan), without ``ignore``."""
    graph = defaultdict(set)
    for e in edges:
        if (e.importer, e.imported) not in ignore:
            graph[e.importer].add(e.imported)
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v: str) -> None:       # recursion depth <= number of modules (~80)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(list(graph)):
        if v not in index:
            visit(v)
    return found


# ---------------------------------------------------------------- the checker itself
def test_parser_sees_function_level_and_relative_imports(tmp_path) -> None:
    pkg = tmp_path / PKG
    (pkg / "a").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "a" / "__init__.py").write_text("from . import x\n")
    (pkg / "a" / "x.py").write_text("def f():\n    from humanoid_reach_ros.a.y import g\n    from .y import g\n")
    (pkg / "a" / "y.py").write_text("import os\nfrom ..a import x\nfrom humanoid_reach_ros import a\n")
    modules = {}
    for path in sorted(pkg.rglob("*.py")):
        parts = list(path.relative_to(tmp_path).with_suffix("").parts)
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    edges = {(e.importer, e.imported, e.line) for m, p in modules.items() for e in imports_of(m, p, modules)}
    assert edges == {(f"{PKG}.a", f"{PKG}.a.x", 1), (f"{PKG}.a.x", f"{PKG}.a.y", 2), (f"{PKG}.a.x", f"{PKG}.a.y", 3),
                     (f"{PKG}.a.y", f"{PKG}.a.x", 2), (f"{PKG}.a.y", f"{PKG}.a", 3)}
    cyc = cycles([Import(a, b, n) for a, b, n in edges])
    assert cyc == [sorted([f"{PKG}.a", f"{PKG}.a.x", f"{PKG}.a.y"])]
    assert cycles([Import("p.a", "p.b", 1), Import("p.b", "p.c", 1)]) == []


# ---------------------------------------------------------------- the package
def test_no_import_cycles() -> None:
    _, edges = import_graph()
    found = cycles(edges, ignore=ALLOWED_CYCLE_EDGES)
    detail = "\n".join(f"  {' <-> '.join(c)}:\n    " + "\n    ".join(str(e) for e in edges
                                                                    if e.importer in c and e.imported in c)
                       for c in found)
    assert not found, f"import cycles:\n{detail}"


def test_allowed_cycle_edges_are_still_needed() -> None:
    """An allow-list entry whose edge is gone must be deleted (the cycle was fixed)."""
    _, edges = import_graph()
    present = {(e.importer, e.imported) for e in edges}
    stale = sorted(ALLOWED_CYCLE_EDGES - present)
    assert not stale, f"these imports are gone: delete them from ALLOWED_CYCLE_EDGES: {stale}"
    still_cyclic = {(a, b) for a, b in ALLOWED_CYCLE_EDGES
                    if any(a in c and b in c for c in cycles(edges))}
    assert still_cyclic == ALLOWED_CYCLE_EDGES, (
        f"no longer part of a cycle: delete from ALLOWED_CYCLE_EDGES: {sorted(ALLOWED_CYCLE_EDGES - still_cyclic)}")


def test_every_module_has_a_layer() -> None:
    modules = module_files()
    unplaced = sorted(m for m in modules if unit(m) not in RANK)
    assert not unplaced, f"add these modules' units to LAYERS in {Path(__file__).name}: {unplaced}"


def test_imports_point_down_the_layers() -> None:
    _, edges = import_graph()
    upward = [e for e in edges if unit(e.importer) != unit(e.imported)
              and RANK[unit(e.imported)] >= RANK[unit(e.importer)]]
    assert not upward, "imports into the same or a higher layer:\n  " + "\n  ".join(map(str, upward))


def test_core_never_imports_io_nodes_or_entry_points() -> None:
    _, edges = import_graph()
    top = {"io", "nodes", "graph", "demo", "warmup", "testing"}
    bad = [e for e in edges if unit(e.importer) in CORE and unit(e.imported) in top]
    assert not bad, "\n".join(map(str, bad))
    assert not [e for e in edges if unit(e.importer) == "control" and unit(e.imported) == "planning"]


def test_the_product_never_imports_the_testing_tools() -> None:
    """``humanoid_reach_ros.testing`` (figures of a running graph, the machine's description) is
    for tests, benches and tools: no other module of the package imports it."""
    _, edges = import_graph()
    bad = [e for e in edges if unit(e.importer) != "testing" and unit(e.imported) == "testing"]
    assert not bad, "\n".join(map(str, bad))
    assert "testing" in RANK and RANK["testing"] == len(LAYERS) - 1


def test_core_never_imports_rclpy_or_messages() -> None:
    """Algorithms never import rclpy or message packages (conversions live in io/)."""
    ros = ("rclpy", "rosbag2_py", "humanoid_reach_interfaces")
    bad = []
    for module, path in module_files().items():
        if unit(module) not in CORE:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
            bad += [f"{module}:{node.lineno} {n}" for n in names
                    if n.split(".")[0] in ros or n.split(".")[0].endswith("_msgs")]
    assert not bad, "\n".join(bad)


def test_the_rest_of_the_package_uses_kinematics_through_its_api():
    """Issue 23: planning, the dual-arm controller, the executor and the nodes use the limb
    solvers through ``humanoid_reach_ros.kinematics`` (the protocol, the registry and the
    compiled pieces it exports), never one of its modules directly."""
    modules = module_files()
    bad = [str(imp) for mod, path in modules.items() if not mod.startswith(f"{PKG}.kinematics")
           for imp in imports_of(mod, path, modules)
           if imp.imported.startswith(f"{PKG}.kinematics.")]
    assert not bad, "import the kinematics package's API, not its modules:\n" + "\n".join(bad)


def test_no_class_name_is_defined_twice() -> None:
    """One concept, one name: no two top-level classes of the package share a name (issue 25)."""
    seen: dict[str, list[str]] = defaultdict(list)
    for module, path in module_files().items():
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ClassDef):
                seen[node.name].append(module)
    twice = {name: modules for name, modules in seen.items() if len(modules) > 1}
    assert not twice, twice
