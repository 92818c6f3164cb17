"""The package's layers (docs/ARCHITECTURE.md): imports point down, no import cycles, no
module over 500 lines, no private name imported from another module."""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "online_em_slam"
# Layer of each subpackage; a module may import from its own subpackage or a lower layer.
LAYERS = {"core": 0, "pipeline": 1, "messages": 1, "parameters": 1, "bag": 1, "baselines": 1,
          "offline": 2, "ros": 2, "datasets": 3, "experiments": 4}
CORE_LAYERS = {"config": 0, "config_fields": 0, "noise_learning_config": 0, "types": 0, "models": 1,
               "weighted": 2, "mapping": 3, "em": 4, "filter": 5, "fleet": 6, "__init__": 7}
MAX_LINES = 500


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imports(name: str, path: Path) -> list[tuple[str, list[str]]]:
    """(absolute module, imported names) of every ``from ... import`` in the module."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target.split(".")[0] == PACKAGE.name:
                out.append((target, [a.name for a in node.names]))
    return out


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        targets = set()
        for target, names in _imports(name, path):
            targets |= {t for t in [target] + [f"{target}.{n}" for n in names] if t in modules and t != name}
        graph[name] = targets
    return graph


def _layer(name: str) -> tuple[int, int]:
    parts = name.split(".")
    top = LAYERS.get(parts[1], -1) if len(parts) > 1 else 99
    inner = CORE_LAYERS.get(parts[2] if len(parts) > 2 else "__init__", 7) if top == 0 else 0
    return top, inner


def test_every_subpackage_has_a_layer():
    subpackages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    assert subpackages == set(LAYERS)


def test_imports_point_down():
    upward = []
    for name, targets in _graph().items():
        for target in targets:
            same = name.split(".")[1:2] == target.split(".")[1:2]
            if same and name.split(".")[1] != "core":
                continue
            if same and name.split(".")[2:3] == target.split(".")[2:3]:
                continue
            if _layer(target) > _layer(name):
                upward.append(f"{name} -> {target}")
    assert not upward, upward


def test_no_import_cycles():
    graph = _graph()
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(v):                                   # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    assert not cycles, cycles


def test_modules_are_short():
    long = {name: n for name, path in _modules().items() if (n := len(path.read_text().splitlines())) > MAX_LINES}
    assert not long, long


def test_no_private_names_imported_across_modules():
    private = [f"{name}: {target}.{n}" for name, path in _modules().items()
               for target, names in _imports(name, path) for n in names
               if n.startswith("_") and not n.startswith("__")]
    assert not private, private
