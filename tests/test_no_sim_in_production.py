"""Production code never imports the simulated cell (cell/sim): the device registry and the
bus and camera factories name its modules as strings, imported only when a config asks for
the simulated devices. Every module of cell/ and drivers/ outside cell/sim is scanned with
the AST, imports inside functions included. The one exception is named with its reason."""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: ``cellctl run --sim`` is the main job: it starts the simulated PLC (a real Modbus client)
ALLOWED = {"cell/commands/run.py": {"cell.sim.plc"}}


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
    return out


def test_production_modules_do_not_import_the_simulation():
    bad = []
    for top in ("cell", "drivers"):
        for path in sorted((ROOT / top).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel.startswith("cell/sim/"):
                continue
            sim = {m for m in _imports(path) if m == "cell.sim" or m.startswith("cell.sim.")}
            sim -= {m for m in sim for a in ALLOWED.get(rel, ()) if m == a or m.startswith(a + ".")}
            if sim:
                bad.append(f"{rel}: {sorted(sim)}")
    assert not bad, "production code imports the simulation:\n" + "\n".join(bad)


def test_the_scan_sees_an_import_inside_a_function(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from cell.sim.plant import Plant\n    return Plant\n")
    assert "cell.sim.plant" in _imports(f)
