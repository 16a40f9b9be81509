"""The layout of the code (docs/design.md §1): imports go forward along the data flow, never back, and
never by a name string except the documented ``--agent module:Class`` loader.

Stages, in the order of the data flow (a module may import its own stage and earlier ones):

    files  <  sumo_nets, controller  <  scenarios  <  harness  <  scimm  <  model  <  sumo_scimm

(``files`` is not a stage: the whole-or-nothing file writes every stage uses)

and inside harness, its subpackages in this order:

    common  <  sim  <  sensors  <  scoring  <  loop  <  expert  <  runs

Imports are read from the source with ``ast`` (every ``import`` statement, at module level
or inside a function), so lazy imports count too.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STAGES = {"files": -1, "sumo_nets": 0, "controller": 0, "scenarios": 1, "harness": 2, "scimm": 3, "model": 4, "sumo_scimm": 5}
HARNESS = {"common": 0, "sim": 1, "sensors": 2, "scoring": 3, "loop": 4, "expert": 5, "runs": 6}
# the one place a module is imported by a name string: the agent loader of --agent module:Class
NAME_STRING_LOADER = "harness/loop/agent.py"


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every module of every stage."""
    out = {}
    for stage in STAGES:
        for path in sorted((ROOT / stage).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


MODULES = _modules()


def _imports(path: Path, name: str) -> set[str]:
    """The project modules ``path`` imports (``from a.b import c`` counts a.b.c if it is a module)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        found.update(t for t in targets if t in MODULES)
    return found


GRAPH = {name: _imports(path, name) for name, path in MODULES.items()}


def _rank(module: str) -> tuple[int, int]:
    parts = module.split(".")
    sub = HARNESS.get(parts[1], -1) if parts[0] == "harness" and len(parts) > 1 else -1
    return STAGES[parts[0]], sub


def test_every_stage_and_harness_subpackage_is_known():
    tops = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file()} - {"tests"}
    assert tops == set(STAGES), "a new top-level package needs its place in the data flow"
    subs = {p.name for p in (ROOT / "harness").iterdir() if (p / "__init__.py").is_file()}
    assert subs == set(HARNESS), "a new harness subpackage needs its place in the order"
    flat = sorted(p.name for p in (ROOT / "harness").glob("*.py") if p.name != "__init__.py")
    assert flat == [], "harness/ holds subpackages only"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_go_forward_along_the_data_flow(module):
    backward = [m for m in sorted(GRAPH[module]) if _rank(m) > _rank(module)
                and not (m.split(".")[0] == module.split(".")[0] == "harness" and _rank(m)[1] == -1)]
    assert backward == [], f"{module} imports later stages: {backward}"


def test_no_import_cycle():
    done: set[str] = set()

    def visit(node: str, path: list[str]) -> None:
        if node in path:
            raise AssertionError("import cycle: " + " -> ".join(path[path.index(node):] + [node]))
        if node in done:
            return
        for nxt in sorted(GRAPH[node]):
            visit(nxt, path + [node])
        done.add(node)

    for module in sorted(GRAPH):
        visit(module, [])


def test_the_cycle_check_finds_a_cycle():
    global GRAPH
    saved = GRAPH
    GRAPH = {"a": {"b"}, "b": {"a"}}
    try:
        with pytest.raises(AssertionError, match="a -> b -> a"):
            test_no_import_cycle()
    finally:
        GRAPH = saved


def test_no_module_is_imported_by_a_name_string_but_agents():
    users = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            called = node.func if isinstance(node, ast.Call) else None
            label = (called.attr if isinstance(called, ast.Attribute) else
                     called.id if isinstance(called, ast.Name) else "")
            if label in ("import_module", "__import__"):
                users.append(path.relative_to(ROOT).as_posix())
    assert sorted(set(users)) == [NAME_STRING_LOADER]


def test_the_command_line_sees_every_stage():
    reached, todo = set(), ["sumo_scimm.cli"]
    while todo:
        m = todo.pop()
        if m not in reached:
            reached.add(m)
            todo += GRAPH[m]
    assert {m.split(".")[0] for m in reached} == set(STAGES)


def test_only_the_simulated_world_calls_libsumo():
    callers = sorted(path.relative_to(ROOT).as_posix() for path in MODULES.values()
                     if any(isinstance(n, (ast.Import, ast.ImportFrom)) and
                            ("libsumo" in [a.name for a in n.names] if isinstance(n, ast.Import) else n.module == "libsumo")
                            for n in ast.walk(ast.parse(path.read_text()))))
    assert callers, "libsumo is imported somewhere"
    outside = [c for c in callers if not c.startswith("harness/sim/")]
    assert outside == [], f"libsumo imported outside harness/sim: {outside}"
