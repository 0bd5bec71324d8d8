"""The package's shape, read from its source (no import): layers, import circles, sizes.

Layers, each importing only itself and the layers below it (docs/architecture.md,
"Layers and layout")::

    contract  <-  envs  <-  agent  <-  deploy  <-  evaluation  <-  training
              <-  analysis, bench  <-  study  <-  cli
    contract  <-  runner  <-  deploy, evaluation, training, analysis, bench, study, cli

``fileio`` (atomic writes), ``stats`` (intervals over seeds: numpy and scipy) and the root
(``__version__``) may be imported by any layer but ``contract``; ``contract`` and
``runner`` must import nothing that the car lacks (JAX, flax, optax, orbax, MuJoCo):
tests/runner/test_no_jax.py runs the runner with those blocked. Every import counts,
function-level ones included (not those under ``if TYPE_CHECKING``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("advisor_jax", "envs")
MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 100

RANK = {"contract": 0, "envs": 1, "agent": 2, "deploy": 3, "evaluation": 4, "training": 5,
        "analysis": 6, "bench": 6, "study": 7, "cli": 8}  # fmt: skip
UTILITIES = {"fileio", "stats", "advisor_jax"}
NUMPY_ONLY = {"contract", "runner"}
CAR_LACKS = {"jax", "jaxlib", "flax", "optax", "orbax", "mujoco", "mujoco_mjx"}


def _modules() -> dict[str, Path]:
    """{dotted module name: file} of every module of the packages."""
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            parts = parts[:-1] if parts[-1] == "__init__" else parts
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _type_checking(node: ast.AST) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def _imported_names(tree: ast.AST):
    """Every module name an import statement names (``from a.b import c``: ``a.b.c`` if
    that is a module, else ``a.b``), skipping ``if TYPE_CHECKING`` blocks."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if _type_checking(node):
            continue
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                yield full if full in MODULES else node.module
        stack.extend(ast.iter_child_nodes(node))


def _imports() -> dict[str, set[str]]:
    """{module: the names it imports}."""
    return {name: set(_imported_names(ast.parse(path.read_text())))
            for name, path in MODULES.items()}  # fmt: skip


IMPORTS = _imports()


def _layer(module: str) -> str:
    """``contract``, ``envs``, ``agent``, ..., ``fileio``, or ``advisor_jax`` (the root)."""
    parts = module.split(".")
    if parts[0] == "envs":
        return "envs"
    return parts[1] if len(parts) > 1 else parts[0]


def _internal(name: str) -> str | None:
    """The module of ours that an imported name is (or lies in), or None."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _allowed(source: str, target: str) -> bool:
    if source == target or target in UTILITIES:
        return source != "contract" or target == "contract"
    if source == "runner":
        return target == "contract"
    if target == "runner":
        return source in {"deploy", "evaluation", "training", "analysis", "bench", "study", "cli"}
    if source in RANK and target in RANK:
        return RANK[target] < RANK[source]
    return False


def test_every_module_has_a_layer():
    layers = {_layer(m) for m in MODULES}
    assert layers <= {*RANK, "runner", *UTILITIES}, layers


def test_layers_import_only_downward():
    wrong = []
    for module, names in IMPORTS.items():
        source = _layer(module)
        for name in names:
            target = _internal(name)
            if target is not None and not _allowed(source, _layer(target)):
                wrong.append(f"{module} ({source}) imports {target} ({_layer(target)})")
    assert not wrong, "\n".join(sorted(wrong))


def test_the_car_side_imports_no_jax():
    wrong = [f"{module} imports {name}" for module, names in IMPORTS.items()
             if _layer(module) in NUMPY_ONLY for name in names
             if name.split(".")[0] in CAR_LACKS]  # fmt: skip
    assert not wrong, "\n".join(sorted(wrong))


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module, or a module importing
    itself (Tarjan)."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []

    def visit(v):
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
            if len(component) > 1 or v in graph[v]:
                out.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_circle():
    """Package ``__init__`` files count as the modules they are: ``envs/__init__.py``
    importing ``envs.navigation`` is an edge, so a module of ``envs`` importing ``envs``
    itself would close a circle."""
    graph = {m: {_internal(n) for n in names} - {None} for m, names in IMPORTS.items()}
    assert _cycles(graph) == []


def test_the_cycle_finder_finds_one():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"a"}}) == [["a"]]


def _long_functions(path: Path) -> list[str]:
    """Functions longer than the limit whose docstring does not say why (a line starting
    with "Long:")."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            lines = node.end_lineno - node.lineno + 1
            reason = "Long:" in (ast.get_docstring(node) or "")
            if lines > MAX_FUNCTION_LINES and not reason:
                out.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_modules_and_functions_are_small(package):
    long_modules = [f"{p.relative_to(ROOT)} ({n} lines)" for p in MODULES.values()
                    if p.is_relative_to(ROOT / package)
                    and (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES]  # fmt: skip
    long_functions = [f for p in MODULES.values() if p.is_relative_to(ROOT / package)
                      for f in _long_functions(p)]  # fmt: skip
    assert not long_modules and not long_functions, "\n".join(long_modules + long_functions)


def test_no_module_or_test_is_named_after_an_issue():
    names = [p for p in [*MODULES.values(), *(ROOT / "tests").rglob("*.py")]
             if "issue" in p.stem.lower()]  # fmt: skip
    assert not names, names
