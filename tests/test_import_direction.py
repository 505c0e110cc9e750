"""Dependencies run one way (docs/architecture.md): every import in holocore, at module level or inside a
function, goes from a later stage to an earlier one. A backwards import fails here with the module that makes
it, before it can become an import cycle that only function-level imports hide."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "holocore"

# Stage of each top-level part of holocore, earliest first; a part may import only parts of a lower stage or
# itself. Parts on one stage do not import each other.
STAGES = (
    ("validate", "formats", "runtime", "options", "plugins", "__init__"),
    ("io",),
    ("display",),
    ("scene",),
    ("trace", "optics"),
    ("plan",),
    ("encode", "evaluate", "render_meta"),
    ("render_setup", "sinks"),
    ("render_passes",),
    ("pipeline",),
    ("baselines",),
    ("calibration",),
)
RANK = {part: i for i, parts in enumerate(STAGES) for part in parts}
# Modules that import nothing of holocore at import time and may be imported from any stage (none now: the
# frame-phase registry the display's optics validate against sits with the display, holocore.display.phase_modes).
LEAVES: set[str] = set()


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT.parent).with_suffix("")
    name = ".".join(rel.parts)
    return name[: -len(".__init__")] if name.endswith(".__init__") else name


def _is_submodule(name: str) -> bool:
    return (ROOT / name).is_dir() or (ROOT / f"{name}.py").is_file()


def _imports(path: Path) -> list[str]:
    """Every holocore module ``path`` imports, at any depth of its code."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module == "holocore":  # submodules by name, or a name of holocore/__init__.py itself
                out += [f"holocore.{a.name}" if _is_submodule(a.name) else "holocore" for a in node.names]
            elif node.module.startswith("holocore."):
                out.append(node.module)
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names if a.name.startswith("holocore.")]
    return out


def _backwards() -> list[str]:
    bad = []
    for path in sorted(ROOT.rglob("*.py")):
        src = _module_name(path)
        for dst in _imports(path):
            a, b = _part(src), _part(dst)
            if a == b or dst in LEAVES:
                continue
            if a not in RANK or b not in RANK:
                bad.append(f"{src} -> {dst}: {a if a not in RANK else b} has no stage in STAGES")
            elif RANK[b] >= RANK[a]:
                bad.append(f"{src} -> {dst}: {b} is not an earlier stage than {a}")
    return bad


def test_every_import_points_to_an_earlier_stage():
    assert _backwards() == []


def test_the_leaves_import_nothing_of_holocore_at_import_time():
    # but the first stage's modules, which import nothing of holocore themselves (the plug-in finder)
    first = {f"holocore.{part}" for part in STAGES[0]}
    for leaf in LEAVES:
        path = ROOT.parent / (leaf.replace(".", "/") + ".py")
        tree = ast.parse(path.read_text())
        top = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
        assert not [n for n in top if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("holocore")
                    and n.module not in first]


def test_a_backwards_import_is_caught(tmp_path, monkeypatch):
    # A trace module importing the pipeline (a later stage) must fail the check.
    fake = tmp_path / "holocore"
    (fake / "trace").mkdir(parents=True)
    (fake / "pipeline.py").write_text("")
    (fake / "trace" / "bad.py").write_text("def f():\n    from holocore.pipeline import render\n")
    monkeypatch.setattr(__import__(__name__, fromlist=["ROOT"]), "ROOT", fake)
    assert _backwards() == ["holocore.trace.bad -> holocore.pipeline: pipeline is not an earlier stage than trace"]


@pytest.mark.parametrize("part", sorted({_part(_module_name(p)) for p in ROOT.rglob("*.py")}))
def test_every_part_has_a_stage(part):
    assert part in RANK, f"holocore.{part} is missing from STAGES"


def test_the_architecture_page_holds_the_stages_in_this_order():
    line = " -> ".join(", ".join(p for p in parts if p != "__init__") for parts in STAGES)
    assert line in (ROOT.parent / "docs/architecture.md").read_text(), line
