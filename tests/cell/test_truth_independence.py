"""The validation's truth shares nothing with the fitter: every module of cell/truth/ is
read (AST), and every import in it, at module level or inside a function, absolute or
relative, ``import x``, ``from x import y``, ``from cell import y`` or a literal
``importlib.import_module("x")`` / ``__import__("x")``, must stay inside cell.truth or
outside the project. The modules the issue names (diagnosis, chain, calibration, effects,
the plant, the presets, compensation, the campaign reader and writer) are checked by name
as well, so the message says which one leaked in."""
import ast
from pathlib import Path

import pytest

import cell.truth

TRUTH = Path(cell.truth.__file__).parent
FITTER_SIDE = ("cell.diagnosis", "cell.calibration", "cell.effects", "cell.sim",
               "cell.kinematics", "cell.compensation", "cell.measurements", "drivers")
MODULES = sorted(TRUTH.glob("*.py"))


def imports_of(path: Path) -> set[str]:
    """Every module name ``path`` imports (``from a import b`` gives ``a`` and ``a.b``)."""
    package = "cell.truth"
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            out.add(base)
            out |= {f"{base}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name in ("import_module", "__import__"):
                out.add(node.args[0].value)
    return out


def test_every_truth_module_is_scanned():
    names = {p.stem for p in MODULES}
    assert {"model", "parts", "campaign", "chain", "chain_campaign", "files", "verdict"} <= names


@pytest.mark.parametrize("path", MODULES, ids=[p.name for p in MODULES])
def test_truth_module_imports_nothing_from_the_fitter_side(path):
    found = imports_of(path)
    leaked = sorted(m for m in found if any(m == f or m.startswith(f + ".") for f in FITTER_SIDE))
    assert not leaked, f"{path.name} imports {leaked}"
    project = sorted(m for m in found if (m == "cell" or m.startswith("cell."))
                     and not (m == "cell.truth" or m.startswith("cell.truth.")))
    assert not project, f"{path.name} imports project modules outside cell.truth: {project}"


def test_the_scan_sees_hidden_imports(tmp_path):
    """The scanner itself: a function-level import, a relative one, ``from cell import x``
    and an importlib call are all reported."""
    src = tmp_path / "probe.py"
    src.write_text("import importlib\n"
                   "def f():\n    from cell.diagnosis.replay import first_step_dirs\n"
                   "def g():\n    from .. import effects\n"
                   "from cell import kinematics\n"
                   "m = importlib.import_module('cell.sim.plant')\n")
    found = imports_of(src)
    assert {"cell.diagnosis.replay", "cell.effects", "cell.kinematics", "cell.sim.plant"} <= found
