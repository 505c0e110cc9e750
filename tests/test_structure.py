"""The project keeps its structural rules (scripts/structure_report.py): no import cycle among its modules,
imports inside functions counted; the hologram's options declared once; no piece over the length limits that
was not already known; the function-level imports and wide lines no more than when the limits were set. The
service is layered like holocore's stages: the domain modules below the workers below the API below the server."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from scripts.structure_report import cycles, import_graph

REPO = Path(__file__).resolve().parents[1]
SERVICE_LAYERS = ("domain", "workers", "api", "server")


def test_the_structure_report_is_green():
    r = subprocess.run([sys.executable, str(REPO / "scripts/structure_report.py")], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "import cycles (imports inside functions counted): 0" in r.stdout


def test_a_cycle_hidden_in_a_function_is_found(tmp_path):
    (tmp_path / "holocore").mkdir()
    (tmp_path / "holocore/a.py").write_text("from holocore import b\n")
    (tmp_path / "holocore/b.py").write_text("def f():\n    from holocore.a import x\n")
    graph, own_late, _ = import_graph(sorted((tmp_path / "holocore").glob("*.py")), root=tmp_path)
    assert cycles(graph) == [["holocore.a", "holocore.b"]] and own_late == 1


def _service_layer(module: str) -> str:
    part = module.split(".")[1] if "." in module else ""
    return {"api": "api", "workers": "workers", "server": "server"}.get(part, "domain")


def test_the_service_imports_only_its_own_layer_or_lower():
    bad = []
    for path in sorted((REPO / "service").rglob("*.py")):
        src = ".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__")
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("service."):
                a, b = _service_layer(src), _service_layer(node.module)
                if SERVICE_LAYERS.index(b) > SERVICE_LAYERS.index(a):
                    bad.append(f"{src} ({a}) -> {node.module} ({b})")
                private = [n.name for n in node.names if n.name.startswith("_")]
                if private:
                    bad.append(f"{src} takes private {', '.join(private)} from {node.module}")
    assert bad == []
