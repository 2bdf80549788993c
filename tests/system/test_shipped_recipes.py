"""Every recipe shipped in ``recipes/`` runs: a production recipe runs 100 parts on the
simulated cell within its own tolerance, with no fault; an example (``production: false``)
is refused by ``run`` unless asked for with ``--allow-examples``. Real ``cellctl`` in a child
process, the built-in simulated cell (seed 0)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cell.recipes import parse_recipe
from tests.system.conftest import REPO

SHIPPED = sorted((REPO / "recipes").glob("*.yaml"))
PARTS = 100


def _recipe(path: Path):
    return parse_recipe(path.read_text(encoding="utf-8"), str(path))


def _run(tmp_path, *args, timeout=600):
    return subprocess.run([sys.executable, "-m", "cell.cli", "run", "--sim", "--db", str(tmp_path / "log.sqlite"),
                           *args], cwd=REPO, capture_output=True, text=True, timeout=timeout)


def test_recipes_are_shipped():
    assert [p.stem for p in SHIPPED if _recipe(p).production], "no production recipe shipped"


@pytest.mark.slow
@pytest.mark.parametrize("path", [p for p in SHIPPED if _recipe(p).production], ids=lambda p: p.stem)
def test_every_production_recipe_runs_100_parts_within_its_tolerance(path, tmp_path):
    recipe = _recipe(path)
    out = _run(tmp_path, "--recipe", recipe.name, "--cycles", str(PARTS), "--json")
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    cycles = json.loads(out.stdout)["cycles"]
    assert len(cycles) == PARTS and all(c["fault"] is None for c in cycles)
    worst = max(c["final_error_mm"] for c in cycles)
    assert worst <= recipe.verify.tolerance_mm, (worst, recipe.verify.tolerance_mm)


@pytest.mark.parametrize("path", [p for p in SHIPPED if not _recipe(p).production], ids=lambda p: p.stem)
def test_an_example_recipe_is_refused_unless_asked_for(path, tmp_path):
    recipe = _recipe(path)
    out = _run(tmp_path, "--recipe", recipe.name, "--cycles", "1")
    assert out.returncode == 2 and "not for production" in out.stderr and "--allow-examples" in out.stderr
    assert not (tmp_path / "log.sqlite").exists()          # refused before the cell started
    out = _run(tmp_path, "--recipe", recipe.name, "--cycles", "1", "--allow-examples", "--json")
    cycles = json.loads(out.stdout)["cycles"]
    assert [c["recipe"] for c in cycles] == [recipe.name]    # it ran (its result is its own)


def test_an_example_in_the_folder_is_no_rejected_edit_for_the_plc(harness):
    """The cell starts beside pin-b (an example it does not allow): the refusal is audited,
    but the PLC is not told an edit was rejected (recipe_status stays 0), and selecting the
    example's number answers "unknown recipe" (1), as for any recipe the cell does not run."""
    h = harness
    rows = [a for a in h.cell.cyclelog.audit_rows() if a["target"].endswith("pin-b.yaml")]
    assert [r["action"] for r in rows] == ["recipe_reject"] and "not for production" in rows[0]["result"]
    assert h.plc.inputs()["recipe_status"] == 0
    h.plc.select_recipe(_recipe(REPO / "recipes" / "pin-b.yaml").number)
    h.wait(lambda: h.plc.inputs()["recipe_status"] == 1, what="recipe_status 1 (unknown)")
    assert h.cycle()["done"] == 1                                  # fast-a still runs
