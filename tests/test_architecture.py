"""The package's import graph, from the source: layers point down, no cycles, no private names across modules.

Every import of a ``fracture_cli`` module counts, at module level or inside a function
(imports under ``if TYPE_CHECKING:`` do not: they never run). A module's layer is its
first package under ``fracture_cli`` (or its own name for the modules at the top);
:data:`LAYERS` lists them from the top down, and a module may import only from its own
layer or a lower one.
"""

from __future__ import annotations

import ast
import pathlib

PACKAGE = pathlib.Path(__file__).resolve().parent.parent / "fracture_cli"

# From the top down; one row may hold several layers that never import each other.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("testing",),
    ("__main__",),
    ("cli",),
    ("batch",),
    ("pipeline",),
    ("atlas",),
    ("view",),
    ("checks",),
    ("stages",),
    ("io",),
    ("runtime",),
    ("types", "options"),
    ("geometry",),
    ("system", "errors", "__init__"),
)
RANK = {name: i for i, row in enumerate(LAYERS) for name in row}
TOP_LEVEL_LIMIT = 8


def module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def modules() -> dict[str, pathlib.Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py")) if "__pycache__" not in p.parts}


def layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imports(path: pathlib.Path, known: set[str]) -> list[tuple[str, str, int]]:
    """``(imported module, name taken or '', line)`` for every package import that runs."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found: list[tuple[str, str, int]] = []

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _type_checking(child):
                for sub in child.orelse:
                    visit(sub)
                continue
            if isinstance(child, ast.Import):
                found.extend((a.name, "", child.lineno) for a in child.names if a.name.startswith("fracture_cli"))
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and (child.module or "").startswith(
                    "fracture_cli"):
                base = child.module or ""
                for alias in child.names:
                    sub = f"{base}.{alias.name}"
                    found.append((sub, "", child.lineno) if sub in known else (base, alias.name, child.lineno))
            visit(child)

    visit(tree)
    return found


def graph() -> dict[str, list[tuple[str, str, int]]]:
    mods = modules()
    known = set(mods)
    return {m: imports(p, known) for m, p in mods.items()}


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    import sys
    sys.setrecursionlimit(10000)
    for v in sorted(edges):
        if v not in index:
            strong(v)
    return out


def _edges(g: dict[str, list[tuple[str, str, int]]]) -> dict[str, set[str]]:
    known = set(g)
    edges: dict[str, set[str]] = {}
    for m, imps in g.items():
        for target, _, _ in imps:
            # importing a submodule runs its packages' __init__ too, but those are not the dependency a
            # reader of the import sees; the edge is to the module named
            if target in known and target != m:
                edges.setdefault(m, set()).add(target)
    return edges


def upward(g: dict[str, list[tuple[str, str, int]]]) -> list[str]:
    bad = []
    for m, imps in g.items():
        for target, _, line in imps:
            if target not in g:
                continue
            if RANK[layer(target)] < RANK[layer(m)]:
                bad.append(f"{m}:{line} imports {target} ({layer(m)} -> {layer(target)})")
    return bad


def private(g: dict[str, list[tuple[str, str, int]]]) -> list[str]:
    bad = []
    for m, imps in g.items():
        for target, name, line in imps:
            leaf = target.rsplit(".", 1)[-1]
            if (name.startswith("_") and not name.startswith("__")) or (leaf.startswith("_") and leaf != "__init__"
                                                                         and not leaf.startswith("__")):
                bad.append(f"{m}:{line} takes {target}{'.' + name if name else ''}")
    return bad


def _import_blocks(tree: ast.AST):
    """(first line, last line, [ImportFrom of fracture_cli ...]) per block inside a function (1-based lines)."""
    out = []

    def lists(node):
        for name in ("body", "orelse", "finalbody"):
            seq = getattr(node, name, None)
            if isinstance(seq, list) and seq and isinstance(seq[0], ast.stmt):
                yield seq
        for h in getattr(node, "handlers", []) or []:
            yield h.body

    def visit(node, inside):
        for seq in lists(node):
            block = []
            for stmt in seq + [None]:
                if isinstance(stmt, (ast.Import, ast.ImportFrom)):
                    block.append(stmt)
                    continue
                ours = [n for n in block if isinstance(n, ast.ImportFrom) and (n.module or "").startswith(
                    "fracture_cli")]
                if inside and ours:
                    out.append((block[0].lineno, block[-1].end_lineno, ours))
                block = []
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and getattr(child.test, "id", None) == "TYPE_CHECKING":
                continue
            visit(child, inside or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)))

    visit(tree, False)
    return sorted({(a, b): (a, b, c) for a, b, c in out}.values(), key=lambda t: t[0])


def _uncommented(text: str):
    lines = text.splitlines()
    bad = []
    for first, last, ours in _import_blocks(ast.parse(text)):
        prev = lines[first - 2].strip() if first >= 2 else ""
        if prev.startswith("#") or any("#" in lines[i - 1] for i in range(first, last + 1)):
            continue
        bad.append((first, ours))
    return bad


def test_function_level_imports_say_why():
    """Imports inside functions exist for start-up time (or to load a heavy dependency only when used): each
    block of them says so in a comment."""
    bad = [f"{m}:{line}" for m, p in modules().items() for line, _ in _uncommented(p.read_text(encoding="utf-8"))]
    assert bad == []


def test_every_layer_is_declared():
    assert {layer(m) for m in modules()} <= set(RANK)


def test_no_import_cycles():
    assert cycles(_edges(graph())) == []


def test_imports_only_point_down():
    assert upward(graph()) == []


def test_no_private_names_across_modules():
    assert private(graph()) == []


def test_few_modules_at_the_top():
    top = [p.name for p in PACKAGE.glob("*.py")]
    assert len(top) <= TOP_LEVEL_LIMIT, sorted(top)


def test_no_module_over_500_lines():
    long = {m: n for m, p in modules().items() if (n := len(p.read_text(encoding="utf-8").splitlines())) > 500}
    assert long == {}


def test_every_stage_has_its_home():
    from fracture_cli.pipeline import STAGES

    homes = {row.name: (PACKAGE / "stages" / f"{row.name}.py", PACKAGE / "stages" / row.name / "__init__.py")
             for row in STAGES}
    assert [name for name, (file, package) in homes.items() if not (file.exists() or package.exists())] == []


def test_readme_package_map_names_every_package():
    readme = (PACKAGE.parent / "README.md").read_text(encoding="utf-8")
    block = readme[readme.index("    fracture_cli/   the package"):readme.index("    recipes/ ")]
    top = sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists())
    assert [name for name in top if f"  {name}/ " not in block] == []
    stage_packages = sorted(p.name for p in (PACKAGE / "stages").iterdir() if (p / "__init__.py").exists())
    assert [name for name in stage_packages if f"{name}/" not in block] == []


if __name__ == "__main__":
    g = graph()
    for c in cycles(_edges(g)):
        print("cycle:", " ".join(c))
    for u in upward(g):
        print("up:", u)
    for p in private(g):
        print("private:", p)
