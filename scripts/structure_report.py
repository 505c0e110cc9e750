"""The project's shape in numbers, and whether it keeps its rules (docs/architecture.md): the hologram's options
declared outside their one model, import cycles among the project's modules (counting imports inside functions),
function-level imports of the project's own modules, the longest modules and functions, and lines over 120
columns. Run: ``.venv/bin/python scripts/structure_report.py``; it exits 1 when a rule is broken.

The rules: no import cycle; an option is declared only in holocore.options (or where :data:`OPTION_COPIES`
says why); no module over 400 lines, no function over 80, no line over 120 columns; function-level imports of the
project's own modules at most :data:`MOST_OWN_LATE_IMPORTS` (the number may only go down), and outside holo/ each
of them only where at the top it would load a package of :data:`STARTUP_PACKAGES` its module does not load (the
report names them). ``tests/test_structure.py`` runs it.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("holocore", "service", "display_agent", "holo")
MODULE_LINES, FUNCTION_LINES, LINE_COLUMNS = 400, 80, 120
# Option fields a class other than the model declares, and why (module:class -> fields).
OPTION_COPIES = {
    "holocore.render_setup:RenderOptions": "the renderer's own dataclass with its kernel fields; built by "
                                           "RenderOptions.from_options and checked by holocore.options.check",
    "holocore.baselines.adam_budget:AdamOptions": "a baseline's fit: its own frames and Adam steps, not the "
                                                  "hologram's",
}
MOST_OWN_LATE_IMPORTS = 132
# Packages whose import a process pays for at start-up; a function-level import is kept only where, at the top, it
# would load one of these that its module does not load already (holo's commands: where it would load holocore's
# numerics into every `holo` command, `holo agent` on a lab PC included).
STARTUP_PACKAGES = frozenset({"torch", "mitsuba", "drjit", "scipy", "numpy", "PIL", "skimage", "ray", "matplotlib",
                              "fastapi", "httpx", "uvicorn", "pygame", "serial", "selenium"})


def _files() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py"))


def _module(path: Path, root: Path = REPO) -> str:
    name = ".".join(path.relative_to(root).with_suffix("").parts)
    return name.removesuffix(".__init__")


def _target(module: str, names: list[str], known: set[str]) -> list[str]:
    """The project modules an ``from module import names`` loads: a named submodule, else the module."""
    subs = [f"{module}.{n}" for n in names if f"{module}.{n}" in known]
    return subs or ([module] if module in known else [])


def import_graph(files: list[Path], root: Path = REPO) -> tuple[dict[str, set[str]], int, int]:
    """(module -> the project modules it imports anywhere in its code but its ``if TYPE_CHECKING:`` blocks,
    function-level imports of the project's modules, all function-level imports)."""
    known = {_module(p, root) for p in files}
    graph: dict[str, set[str]] = defaultdict(set)
    own_late = all_late = 0
    for path in files:
        src = _module(path, root)
        tree = ast.parse(path.read_text(), filename=str(path))
        late = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                for n in ast.walk(f) if isinstance(n, (ast.Import, ast.ImportFrom))}
        typing_only = {id(n) for b in ast.walk(tree) if isinstance(b, ast.If) and "TYPE_CHECKING" in ast.unparse(b.test)
                       for n in ast.walk(b)}  # annotations only: never run
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                dst = _target(node.module, [a.name for a in node.names], known)
            elif isinstance(node, ast.Import):
                dst = [a.name for a in node.names if a.name in known]
            else:
                continue
            if id(node) in late:
                all_late += 1
                own_late += bool(dst)
            graph[src].update(d for d in dst if d != src)
    return graph, own_late, all_late


def _top_imports(files: list[Path]) -> dict[str, tuple[set[str], set[str]]]:
    """module -> (the project modules it imports at its top, outside ``if TYPE_CHECKING:``, its package parents
    included; the start-up packages it imports there)."""
    known = {_module(p) for p in files}
    out = {}
    for path in files:
        mod = _module(path)
        tree = ast.parse(path.read_text(), filename=str(path))
        own = {".".join(mod.split(".")[:i]) for i in range(1, mod.count(".") + 1)} & known
        ext: set[str] = set()
        for node in tree.body:
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                own |= set(_target(node.module, [a.name for a in node.names], known))
                ext |= {node.module.split(".")[0]} & STARTUP_PACKAGES
            elif isinstance(node, ast.Import):
                own |= {a.name for a in node.names if a.name in known}
                ext |= {a.name.split(".")[0] for a in node.names} & STARTUP_PACKAGES
        out[mod] = (own, ext)
    return out


def late_imports_without_reason(files: list[Path]) -> tuple[list[str], dict[str, int]]:
    """(``module:line -> target`` for each function-level import of a project module outside holo/ that would
    load no start-up package at the top that its module does not load already, so nothing keeps it inside; how
    many of the others defer each package)."""
    top = _top_imports(files)
    loads = {mod: set(ext) for mod, (_, ext) in top.items()}  # the start-up packages each module loads, closed
    changed = True
    while changed:
        changed = False
        for mod, (own, _) in top.items():
            more = set().union(*(loads.get(m, set()) for m in own)) - loads[mod]
            if more:
                loads[mod] |= more
                changed = True
    known = set(top)
    unneeded, deferred = [], {}
    for path in files:
        mod = _module(path)
        if mod == "holo" or mod.startswith("holo."):
            continue  # holo.app loads every command: tests/agent/test_config_hooks.py holds them light
        for f in ast.walk(ast.parse(path.read_text())):
            if not isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(f):
                if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    for target in _target(node.module, [a.name for a in node.names], known):
                        extra = loads.get(target, set()) - loads[mod]
                        if not extra:
                            unneeded.append(f"{mod}:{node.lineno} -> {target}")
                        for pkg in extra:
                            deferred[pkg] = deferred.get(pkg, 0) + 1
    return unneeded, deferred


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    sys.setrecursionlimit(10_000)
    for v in list(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def option_copies(files: list[Path]) -> list[str]:
    """``module:Class.field`` for each option field that a class of options outside holocore.options declares (a
    class named ``*Options``, ``*Fields`` or ``*Request`` that declares two or more of them: a restated set; a
    result or a meta that records what ran is not one)."""
    sys.path.insert(0, str(REPO))
    from holocore.options import HologramOptions

    fields = set(HologramOptions.model_fields)
    out = []
    for path in files:
        mod = _module(path)
        if mod == "holocore.options":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and node.name.endswith(("Options", "Fields", "Request")):
                own = [item.target.id for item in node.body if isinstance(item, ast.AnnAssign)
                       and isinstance(item.target, ast.Name) and item.target.id in fields]
                out += [f"{mod}:{node.name}.{f}" for f in own] if len(own) >= 2 else []
    return out


def long_pieces(files: list[Path]) -> tuple[list[tuple[int, str]], list[tuple[int, str]], list[str]]:
    """(modules by lines, functions by lines, lines over the column limit as path:line)."""
    modules, functions, wide = [], [], []
    for path in files:
        rel = str(path.relative_to(REPO))
        lines = path.read_text().splitlines()
        modules.append((len(lines), rel))
        wide += [f"{rel}:{i}" for i, line in enumerate(lines, 1) if len(line) > LINE_COLUMNS]
        for node in ast.walk(ast.parse("\n".join(lines))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                functions.append((node.end_lineno - node.lineno + 1, f"{rel}:{node.name}"))
    return sorted(modules, reverse=True), sorted(functions, reverse=True), wide


def main() -> int:
    files = _files()
    graph, own_late, all_late = import_graph(files)
    groups = cycles(graph)
    copies = option_copies(files)
    modules, functions, wide = long_pieces(files)
    unexplained = [c for c in copies if c.rsplit(".", 1)[0] not in OPTION_COPIES]
    too_long = [name for n, name in modules if n > MODULE_LINES]
    too_long += [name for n, name in functions if n > FUNCTION_LINES]
    print(f"modules: {len(files)} in {', '.join(PACKAGES)}")
    print(f"option fields declared outside holocore.options: {len(copies)} ({len(unexplained)} without a reason)")
    for c in copies:
        print(f"  {c}: {OPTION_COPIES.get(c.rsplit('.', 1)[0], 'NO REASON GIVEN')}")
    print(f"import cycles (imports inside functions counted): {len(groups)}")
    for g in groups:
        print(f"  {' <-> '.join(g)}")
    print(f"function-level imports: {all_late}, of the project's own modules {own_late} "
          f"(at most {MOST_OWN_LATE_IMPORTS})")
    unneeded, deferred = late_imports_without_reason(files)
    print("  outside holo/, each keeps a package out of its module's start-up: "
          + ", ".join(f"{pkg} {n}" for pkg, n in sorted(deferred.items(), key=lambda kv: -kv[1]))
          + (f"; {len(unneeded)} defer nothing: {', '.join(unneeded[:6])}" if unneeded else ""))
    print(f"modules over {MODULE_LINES} lines: {sum(n > MODULE_LINES for n, _ in modules)}; longest: "
          + ", ".join(f"{name} {n}" for n, name in modules[:5]))
    print(f"functions over {FUNCTION_LINES} lines: {sum(n > FUNCTION_LINES for n, _ in functions)}; longest: "
          + ", ".join(f"{name} {n}" for n, name in functions[:5]))
    print(f"lines over {LINE_COLUMNS} columns: {len(wide)}" + (f" ({', '.join(wide[:5])}...)" if wide else ""))
    broken = []
    if groups:
        broken.append("import cycles")
    if unexplained:
        broken.append(f"options declared without a reason: {', '.join(unexplained)}")
    if too_long:
        broken.append(f"over the length limits: {', '.join(too_long)}")
    if unneeded:
        broken.append(f"{len(unneeded)} function-level imports that defer no start-up package: move them to the top")
    if own_late > MOST_OWN_LATE_IMPORTS:
        broken.append(f"{own_late} function-level imports of the project's modules, more than "
                      f"{MOST_OWN_LATE_IMPORTS}")
    if wide:
        broken.append(f"{len(wide)} lines over {LINE_COLUMNS} columns")
    print("rules: " + ("kept" if not broken else "BROKEN: " + "; ".join(broken)))
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
