"""The layering rules of docs/architecture.md, checked on the source: module-level imports go
downwards only, there is no import circle, no module is over 1 000 lines, and no document outside
the repository is referred to."""

import ast
from pathlib import Path

import pytest

from fixtures import REPO

PACKAGE = REPO / "olado"
MAX_LINES = 1000
#: the leaf modules every layer may import
LEAVES = {"olado.errors", "olado.options", "olado._registry", "olado.interrupts"}
#: layer -> the olado layers it may import at module level (besides itself and the leaves)
ALLOWED = {
    "olado.linalg": set(),
    "olado.qp": {"olado.linalg", "olado.result"},
    "olado.problems": {"olado.result"},
    "olado.solvers": {"olado.qp", "olado.linalg", "olado.problems", "olado.result"},
    "olado.result": set(),
    "olado.config": {"olado.solvers"},   # the solver table (olado.solvers.registry), to map sections to solvers
    # benchmarks: above the solvers, problems and configs, below only the command line
    "olado.bench": {"olado.solvers", "olado.problems", "olado.config", "olado.result"},
}


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(REPO).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        yield ".".join(parts), path


MODULES = dict(_modules())


def _resolve(module, path, node):
    """olado module names a module-level import statement of ``module`` refers to."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name.split(".")[0] == "olado"]
    base = node.module or ""
    if node.level:
        anchor = package.split(".")
        anchor = anchor[: len(anchor) - node.level + 1]
        base = ".".join(anchor + ([base] if base else []))
    if base.split(".")[0] != "olado":
        return []
    out = []
    for alias in node.names:
        sub = f"{base}.{alias.name}"
        out.append(sub if sub in MODULES else base)
    return out


def _top_level_imports(module, path):
    """Imports executed when the module is imported: module level, including inside try/if
    blocks, excluding function and class bodies (lazy imports) and TYPE_CHECKING blocks."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []

    def visit(body):
        for node in body:
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                found.extend(_resolve(module, path, node))
            elif isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                continue
            elif isinstance(node, (ast.If, ast.Try, ast.With)):
                for field in ("body", "orelse", "finalbody", "handlers"):
                    for child in getattr(node, field, []):
                        visit(child.body if isinstance(child, ast.ExceptHandler) else [child])
    visit(tree.body)
    return sorted(set(m for m in found if m != module))


GRAPH = {m: _top_level_imports(m, p) for m, p in MODULES.items()}


def _layer(module):
    for layer in sorted(ALLOWED, key=len, reverse=True):
        if module == layer or module.startswith(layer + "."):
            return layer
    return None


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_go_downwards(module):
    layer = _layer(module)
    if layer is None:           # api, cli, __init__: the top, may import anything
        return
    for target in GRAPH[module]:
        tl = _layer(target)
        if target in LEAVES or tl == layer or tl is None and target in LEAVES:
            continue
        assert tl in ALLOWED[layer], f"{module} imports {target} at module level ({layer} may import " \
                                     f"{sorted(ALLOWED[layer]) or 'only the leaves'})"


def test_nothing_below_the_top_imports_bench():
    """olado.bench is used by the command line and by users only (lazy imports included)."""
    offenders = []
    for module, path in MODULES.items():
        if module.startswith("olado.bench") or module in ("olado", "olado.cli", "olado.api", "olado.__main__"):
            continue
        if "olado.bench" in path.read_text(encoding="utf-8") or "from ..bench" in path.read_text(encoding="utf-8"):
            offenders.append(module)
    assert not offenders, f"modules below olado.bench refer to it: {offenders}"


def test_no_import_circle():
    index, low, stack, on, cycles = {}, {}, [], set(), []

    def strong(v):
        index[v] = low[v] = len(index)
        stack.append(v); on.add(v)
        for w in GRAPH.get(v, []):
            if w not in index:
                strong(w); low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop(); on.discard(w); comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in GRAPH:
        if v not in index:
            strong(v)
    assert not cycles, f"import circles: {cycles}"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_module_length(module):
    lines = MODULES[module].read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_LINES, f"{MODULES[module].relative_to(REPO)} has {lines} lines (at most {MAX_LINES})"


def test_no_reference_to_documents_outside_the_repository():
    offenders = []
    for path in [*PACKAGE.rglob("*.py"), *REPO.glob("docs/*.md"), REPO / "README.md"]:
        text = path.read_text(encoding="utf-8")
        if "ARCHITECTURE.md" in text:
            offenders.append(str(path.relative_to(REPO)))
    assert not offenders, f"refer to docs/architecture.md instead: {offenders}"
