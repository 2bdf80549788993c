"""``cellctl compensate``: the JSON trace of the issue's example, the table, bad input."""
import json

from cell.cli import main


def test_paper_json_trace_matches_table1_group_a(capsys):
    # seed 000 Table 1 group a: last step (247.8476, 933.4464), min-error 0.0265 mm
    assert main(["compensate", "--method", "paper", "--l1", "500", "--l2", "500", "--start-deg", "60,30",
                 "--unit-deg", "0.01", "--k", "16", "--target", "247.85,933.42", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [round(v, 4) for v in out["steps"][-1]["point_mm"]] == [247.8476, 933.4464]
    assert round(out["final_error_mm"], 4) == 0.0265 and out["moves"] == 4
    assert out["steps"][0]["joints_deg"] == [60.0, 30.0]
    assert all(set(s) >= {"joints_deg", "point_mm", "error_mm"} for s in out["steps"])


def test_default_method_is_ours_and_prints_a_table(capsys):
    assert main(["compensate", "--start-deg", "60,30", "--target", "247.85,933.42"]) == 0
    out = capsys.readouterr().out
    assert "method lattice" in out and "final error 0.0223 mm after 2 moves" in out


def test_bad_input_exits_2_with_a_message(capsys):
    assert main(["compensate", "--target", "2000,0"]) == 2
    assert "out of reach" in capsys.readouterr().err
    assert main(["compensate", "--target", "300,800", "--unit-deg", "0"]) == 2
    assert "--unit-deg" in capsys.readouterr().err
    assert main(["compensate", "--target", "300,800", "--l1", "-5"]) == 2
    assert "l1_mm" in capsys.readouterr().err
