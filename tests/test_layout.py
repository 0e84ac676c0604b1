"""The import graph: the package imports neither its checks nor its tests,
``validation`` imports only the package, and no module imports, directly
or round a cycle, one that imports it (imports inside functions count)."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "plugins"


def module_name(path: Path) -> str:
    base = PACKAGE if path.is_relative_to(PACKAGE) else ROOT
    parts = list(path.relative_to(base).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path, name: str) -> set:
    """Top-level names of the project's modules that ``path`` imports."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[:len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            found.add(target)
            found.update(f"{target}.{alias.name}" for alias in node.names)
    return found


def project_graph() -> dict:
    modules = {}
    for folder in (PACKAGE / "mitsuba_whitted", ROOT / "validation", ROOT / "tests"):
        for path in folder.rglob("*.py"):
            modules[module_name(path)] = path
    return {name: {target for target in imported(path, name) if target in modules
                   and target != name} for name, path in modules.items()}


def test_each_part_imports_only_what_it_may():
    for name, targets in project_graph().items():
        top = name.split(".")[0]
        allowed = {"mitsuba_whitted": {"mitsuba_whitted"},
                   "validation": {"mitsuba_whitted", "validation"},
                   "tests": {"mitsuba_whitted", "validation", "tests"}}.get(top)
        if allowed is None:  # test modules import as top-level names
            allowed = {"mitsuba_whitted", "validation", "conftest"}
        wrong = {target for target in targets if target.split(".")[0] not in allowed}
        assert not wrong, f"{name} imports {sorted(wrong)}"


def test_no_module_is_in_an_import_cycle():
    graph = project_graph()
    # A package imports its submodules to re-export them; the submodules
    # import the package's siblings, not the package itself.
    assert_acyclic({name: {t for t in targets if not name.startswith(t + ".")}
                    for name, targets in graph.items()})


def test_the_package_parts_import_one_way():
    """Parts of the package (``compare``, ``distributed``, ``scene_digest``,
    ...) import each other in one direction, even lazily: a part that its
    user imports back would be a cycle that the module graph misses."""
    graph = {}
    for name, targets in project_graph().items():
        if name.startswith("mitsuba_whitted."):
            graph.setdefault(part(name), set()).update(
                part(t) for t in targets
                if t.startswith("mitsuba_whitted.") and part(t) != part(name))
    assert_acyclic(graph)


def part(name: str) -> str:
    """The package's top-level module or subpackage that ``name`` is in."""
    return ".".join(name.split(".")[:2])


def assert_acyclic(graph: dict) -> None:
    state, path = {}, []

    def visit(node):
        state[node] = "open"
        path.append(node)
        for target in sorted(graph.get(node, ())):
            if state.get(target) == "open":
                cycle = path[path.index(target):] + [target]
                raise AssertionError(" -> ".join(cycle))
            if target not in state:
                visit(target)
        path.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node)
