"""One call diagnoses any campaign (cell/diagnosis/answer.py): the planar and the chain
family answer through the same object, in the same format, text and page alike."""
import json

from cell import effects as fx
from cell.diagnosis.answer import diagnose_campaign
from cell.diagnosis.page import FORMAT, FORMAT_VERSION
from cell.measurements import read_campaign
from cell.sim.campaigns import Design, make_campaign
from cell.truth.chain_campaign import MARKERS, make


def test_planar_and_chain_campaigns_get_one_kind_of_answer(tmp_path):
    offset = fx.make_effect("joint_offset", ("j1",), {"j1_offset_deg": 0.1})
    planar = diagnose_campaign(make_campaign([offset], 21, Design(n_points=100, n_moves=3)))
    chain = diagnose_campaign(read_campaign(make(tmp_path / "chain", {"offset": {"j2": 0.1}},
                                                 poses=40, seed=2, markers=MARKERS)))
    assert planar.report["chain"]["planar"] is True and "planar" not in chain.report["chain"]
    for a, joint, kind in ((planar, "j1", "planar"), (chain, "j2", "chain")):
        rep = json.loads(json.dumps(a.report))
        assert (rep["format"], rep["format_version"]) == (FORMAT, FORMAT_VERSION)
        assert rep["cause"]["effect"] == "joint_offset" and rep["cause"]["joints"] == [joint]
        assert "joint_offset" in a.text()
        index = a.write_html(tmp_path / kind)
        assert index.name == "index.html" and "joint_offset" in index.read_text()


def test_one_text_says_what_the_report_holds_for_either_family(tmp_path):
    offset = fx.make_effect("joint_offset", ("j1",), {"j1_offset_deg": 0.1})
    planar = diagnose_campaign(make_campaign([offset], 21, Design(n_points=100, n_moves=3)))
    chain = diagnose_campaign(read_campaign(make(tmp_path / "chain", {"offset": {"j2": 0.1}},
                                                 poses=40, seed=2, markers=MARKERS)))
    for a in (planar, chain):
        rep, text = a.report, a.text()
        c, h = rep["cause"], rep["holdout"]
        assert f"confidence: {c['confidence']}" in text
        for name, v in c["params"].items():
            assert f"{name} = {v:.6g}" in text
        assert f"{h['rms_before_mm']:.4f} -> {h['rms_after_mm']:.4f} mm" in text
        assert ("\nchain: " in text) == ("chain" in rep)
        assert ("comm lags:" in text) == bool(rep.get("delay"))
        assert ("UNEXPLAINED" in text) == rep["unexplained"]
