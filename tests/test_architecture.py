"""The library's import graph (issue 30, "One house"): no import circle between the modules of
``repro/`` and ``cli/``, and no module importing another module's private name.

Every import counts, wherever it stands: at module level, inside a function (a lazy import hides
a circle, it does not break it), under ``if TYPE_CHECKING``, relative imports resolved, and
``importlib.import_module("a.literal.name")``.  An import names the deepest module it reaches:
``from repro.data.cache import dataset_dir`` is an edge to ``repro.data.cache``,
``from repro.data import registry`` one to ``repro.data.registry``.  Read with :mod:`ast`,
nothing is imported.  The layering the graph follows is in docs/engine.md ("Layers").
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("repro", "cli")


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` under the packages."""
    out = {}
    for base in PACKAGES:
        for p in sorted((root / base).rglob("*.py")):
            parts = list(p.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


def _deepest(name: str, mods) -> str | None:
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def _literal_import_module(node: ast.Call) -> str | None:
    """The module an ``importlib.import_module("...")`` call names by a string literal."""
    f = node.func
    named = (isinstance(f, ast.Attribute) and f.attr == "import_module") or (
        isinstance(f, ast.Name) and f.id == "import_module")
    if named and node.args and isinstance(node.args[0], ast.Constant) \
            and isinstance(node.args[0].value, str):
        return node.args[0].value
    return None


def import_graph(root: Path = ROOT):
    """``(edges, private)``: ``edges[a][b]`` the line numbers where module ``a`` imports module
    ``b``; ``private`` the ``(module, line, imported module, name)`` of every ``_name`` (not a
    dunder, not a submodule) that one module imports from another."""
    mods = modules(root)
    edges: dict[str, dict[str, list[int]]] = {m: {} for m in mods}
    private = []
    for m, path in mods.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        package = m if path.name == "__init__.py" else m.rpartition(".")[0]

        def edge(target: str | None, line: int) -> None:
            if target and target != m:
                edges[m].setdefault(target, []).append(line)

        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    edge(_deepest(a.name, mods), node.lineno)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = package.split(".")
                    parts = parts[:len(parts) - (node.level - 1)]
                    base = ".".join(parts + ([node.module] if node.module else []))
                else:
                    base = node.module or ""
                for a in node.names:
                    full = f"{base}.{a.name}"
                    target = full if full in mods else _deepest(base, mods)
                    edge(target, node.lineno)
                    if (target and target != m and full not in mods and a.name.startswith("_")
                            and not a.name.startswith("__")):
                        private.append((m, node.lineno, target, a.name))
            elif isinstance(node, ast.Call):
                name = _literal_import_module(node)
                if name is not None:
                    edge(_deepest(name, mods), node.lineno)
    return edges, private


def cycles(edges: dict[str, dict[str, list[int]]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative), each
    sorted, in a stable order."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for start in sorted(edges):
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return sorted(out)


def _one_circle(comp: list[str], edges) -> str:
    """One circle through the component's first module, with the import lines:
    ``a (line 12) -> b (line 40) -> a``."""
    inside = set(comp)
    start = comp[0]
    came: dict[str, str] = {}
    todo = [start]
    while todo:  # breadth first, back to start
        nxt = []
        for v in todo:
            for w in sorted(edges[v]):
                if w not in inside:
                    continue
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(came[path[-1]])
                    path.reverse()
                    hops = [f"{a} (line {edges[a][b][0]})" for a, b in
                            zip(path, path[1:] + [start])]
                    return " -> ".join(hops + [start])
                if w not in came:
                    came[w] = v
                    nxt.append(w)
        todo = nxt
    return " ".join(comp)


def test_no_import_cycle():
    edges, _ = import_graph()
    found = cycles(edges)
    assert not found, "import circles between modules (move the shared code down a layer, or "\
        "let the lower module offer a hook; docs/engine.md, Layers):\n" + "\n".join(
            f"- {len(c)} modules {c}\n  e.g. {_one_circle(c, edges)}" for c in found)


def test_no_private_name_imported_across_modules():
    _, private = import_graph()
    assert not private, "private names imported from another module (make them public, with a "\
        "docstring, in the module they belong to, or move them):\n" + "\n".join(
            f"- {m}:{line} imports {name} from {t}" for m, line, t, name in private)


def test_the_checks_see_a_circle_and_a_private_import(tmp_path):
    """The checks themselves: a lazy import closing a circle, a relative import and a private
    name are all found."""
    pkg = tmp_path / "repro" / "sub"
    pkg.mkdir(parents=True)
    (tmp_path / "cli").mkdir()
    (tmp_path / "repro" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .b import _helper\n")
    (pkg / "b.py").write_text("def f():\n    from repro.sub import a\n")
    (pkg / "c.py").write_text("import importlib\nimportlib.import_module('repro.sub.d')\n")
    (pkg / "d.py").write_text("from repro.sub.c import x\n")
    edges, private = import_graph(tmp_path)
    assert cycles(edges) == [["repro.sub.a", "repro.sub.b"], ["repro.sub.c", "repro.sub.d"]]
    assert private == [("repro.sub.a", 1, "repro.sub.b", "_helper")]
    assert _one_circle(["repro.sub.a", "repro.sub.b"], edges) == \
        "repro.sub.a (line 1) -> repro.sub.b (line 2) -> repro.sub.a"
