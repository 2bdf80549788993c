"""Production code never imports simulation code (the simulated cell, cell/sim, and the
drivers' simulated twins, drivers/*/sim*.py: :func:`drivers.registry.is_simulation`), at
load time (the AST of every module) nor at run time (a hardware start in a subprocess):
the device registry and the bus and camera factories name those modules as strings,
imported only when a config asks for the simulated devices. Every module of cell/ and
drivers/ that is not simulation code is scanned with the AST, imports inside functions
included. The one exception is named with its reason."""
from __future__ import annotations

import ast
from pathlib import Path

from drivers.registry import is_simulation

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
            if is_simulation(rel.removesuffix(".py").removesuffix("/__init__").replace("/", ".")):
                continue
            sim = {m for m in _imports(path) if is_simulation(m)}
            sim -= {m for m in sim for a in ALLOWED.get(rel, ()) if m == a or m.startswith(a + ".")}
            if sim:
                bad.append(f"{rel}: {sorted(sim)}")
    assert not bad, "production code imports the simulation:\n" + "\n".join(bad)


def test_simulation_code_is_named_by_where_it_lives():
    sim = ["cell.sim", "cell.sim.plant.arm", "drivers.camera.sim", "drivers.camera.sim_hand",
           "drivers.stations.sim", "drivers.stations.sim_bus"]
    production = ["cell.simple", "cell.devices", "drivers.camera", "drivers.camera.base",
                  "drivers.stations.bus", "drivers.stations.simulink", "drivers"]
    assert [m for m in sim if not is_simulation(m)] == []
    assert [m for m in production if is_simulation(m)] == []


def test_the_scan_sees_an_import_inside_a_function(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    from cell.sim.plant import Plant\n    return Plant\n")
    assert "cell.sim.plant" in _imports(f)


def test_a_hardware_start_loads_no_simulation_module(tmp_path):
    """At run time: ``cellctl serve --config`` with the shipped hardware config (its CAN
    interface missing, so the start stops at the drives, after the app, the devices, the
    drivers, the calibration service and the recipes are loaded) leaves no ``cell.sim``
    module in ``sys.modules``."""
    import json
    import os
    import subprocess
    import sys

    import yaml
    cfg = yaml.safe_load((ROOT / "deploy/cell.yaml").read_text())
    cfg["plc"].update(host="127.0.0.1", allow=[], port=0)
    cfg["plc"]["tls"]["enabled"] = False
    cfg["stations"]["channel"] = "cellnocan8"            # no such interface on any machine
    cfg["log"]["path"] = "cell.sqlite"
    cfg["recipes"]["directory"] = str(ROOT / "recipes")
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cfg))
    probe = ("import json, sys\nfrom cell.cli import main\ncode = main(['serve', '--config', 'cell.yaml', "
             "'--seconds', '1'])\nfrom drivers.registry import is_simulation\n"
             "print(json.dumps({'code': code, 'sim': sorted(m for m in sys.modules "
             "if is_simulation(m)), 'loaded': sorted(m for m in sys.modules "
             "if m.startswith(('cell.', 'drivers.')))}))")
    out = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True,
                         timeout=300, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["code"] == 2, out.stderr[-2000:]                  # stopped at the missing interface
    assert {"cell.app", "cell.devices", "drivers.stations.driver", "cell.calibration.service"} <= set(got["loaded"])
    assert got["sim"] == [], got["sim"]
