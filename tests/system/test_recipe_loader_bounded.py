"""The controller's recipe loader cannot be held: a 0.6 KB "billion laughs" recipe (YAML
aliases nested nine deep, 9^10 ≈ 3.5·10^9 nodes for every walk of the expanded tree) and a file nested 10,000 levels deep
are dropped into the recipe folder of a running cell. Each is rejected and audited naming
what was refused, within the next refreshes of simulated time, and cycles run meanwhile."""
from __future__ import annotations

BOMB = "name: bomb\nnumber: 60\nlol0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n" + "".join(
    f"lol{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]\n" for i in range(1, 10))


def test_an_alias_bomb_and_deep_nesting_in_the_folder_are_refused_while_cycles_run(harness):
    h = harness
    assert len(BOMB.encode()) < 1000
    folder = h.tmp_path / "recipes"
    (folder / "bomb.yaml").write_text(BOMB)
    (folder / "deep.yaml").write_text("name: deep\nnumber: 61\nx: " + "[" * 10_000 + "]" * 10_000 + "\n")
    assert h.cycle()["done"] == 1

    def refused(name):
        return [a for a in h.cell.cyclelog.audit_rows() if a["target"] == str(folder / f"{name}.yaml")]
    h.wait(lambda: refused("bomb") and refused("deep"), timeout_s=5.0, what="both files decided")
    [bomb], [deep] = refused("bomb"), refused("deep")
    assert bomb["action"] == "recipe_reject" and "anchors and aliases (&a0)" in bomb["result"]
    assert deep["action"] == "recipe_reject" and "nested deeper than 16 levels" in deep["result"]
    assert "bomb" not in h.cell.recipes.active and "deep" not in h.cell.recipes.active
    assert h.cycle()["done"] == 1
