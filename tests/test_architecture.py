"""The picture DESIGN.md draws holds in the code: no import circle between scan2terrain modules
(function-local and type-checking imports count: a circle hidden in a function is still one),
a stage never imports a later one (readers -> slam -> octree -> grids -> filters -> geometry ->
replay -> exporters), the shared modules (types, errors, config, fileio, texts, _numba,
_malloc) import no stage and no composer, and every module is in one layer: shared, a stage,
or a composer (world/, steps.py and checks.py below commands/, below cli/ and api.py, the
Python API; the package's __init__ on top, re-exporting the API, imported by no module)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent / "src" / "scan2terrain"
STAGES = ["readers", "slam", "octree", "grids", "filters", "geometry", "replay", "exporters"]
COMPOSERS = {"commands", "cli", "api", "steps", "world", "checks", "warmup"}
SHARED = {"types", "errors", "config", "fileio", "texts", "_numba", "_malloc"}
#: Composers, lowest first: each imports only shared modules, stages and lower composers.
LAYERS = [
    {"world"},
    {"steps", "checks"},
    {"commands"},
    {"cli", "api", "warmup", "__main__"},
    {"package"},  # scan2terrain/__init__.py: the API, re-exported
]


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(("scan2terrain", *parts)).removesuffix(".__init__")


def imports() -> dict[str, set[str]]:
    """Every scan2terrain module -> the scan2terrain modules it imports (anywhere in it)."""
    known = {module_name(p) for p in ROOT.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for path in ROOT.rglob("*.py"):
        name = module_name(path)
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                base = node.module
                for alias in node.names:
                    full = f"{base}.{alias.name}"
                    found.add(full if full in known else base)
            elif isinstance(node, ast.Import):
                found.update(alias.name for alias in node.names)
        graph[name] = {m for m in found if m in known and m != name}
    return graph


def test_no_import_circle() -> None:
    graph = imports()
    state: dict[str, int] = {}
    circles: list[list[str]] = []

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                circles.append([*path[path.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt, path)
        path.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
    assert circles == [], "\n".join(" -> ".join(c) for c in circles)


def stage_of(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 2 and parts[1] in STAGES else None


def test_stages_import_only_earlier_stages() -> None:
    wrong = []
    for module, targets in imports().items():
        stage = stage_of(module)
        if stage is None:
            continue
        for target in targets:
            other = stage_of(target)
            top = target.split(".")[1] if target.count(".") else ""
            if top in COMPOSERS or (other and STAGES.index(other) > STAGES.index(stage)):
                wrong.append(f"{module} imports {target}")
    assert wrong == [], "\n".join(sorted(wrong))


def layer_of(module: str) -> str:
    """'shared', a stage's name, the composer's top-level name, or 'package'."""
    parts = module.split(".")
    if len(parts) == 1:
        return "package"
    return "shared" if parts[1] in SHARED else parts[1]


def test_every_module_has_a_layer_and_imports_only_below_it() -> None:
    composers = [name for group in LAYERS for name in group]
    rank = {name: i for i, group in enumerate(LAYERS) for name in group}
    wrong, unplaced = [], []
    for module, targets in imports().items():
        layer = layer_of(module)
        if layer != "shared" and layer not in STAGES and layer not in composers:
            unplaced.append(module)
            continue
        for target in targets:
            other = layer_of(target)
            if layer == "shared" and other != "shared":
                wrong.append(f"{module} (shared) imports {target}")
            elif layer in rank and other in rank and rank[other] > rank[layer]:
                wrong.append(f"{module} imports {target}, a composer above it")
    assert unplaced == [], unplaced
    assert wrong == [], "\n".join(sorted(wrong))
