"""The chain diagnosis and calibration on campaigns of the independent forward model
(cell.truth.chain) and on the real TIAGo set."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from cell.calibration.chain import calibrate_chain, write_calibrated
from cell.diagnosis.chain.report import diagnose_chain
from cell.measurements import read_campaign
from tests.cell.chain import chainsim

TIAGO = Path(__file__).resolve().parents[2] / "data" / "real" / "tiago-mocap-train"  # copy of shared/data/real
NOISE = 0.05


@pytest.mark.parametrize("effects, effect, joints, truth", [
    ({"offset": {"j2": 0.05, "j3": -0.08}}, "joint_offset", ["j2", "j3"],
     {"j2_offset_deg": 0.05, "j3_offset_deg": -0.08}),
    ({"ratio": {"j2": 0.002}}, "gear_ratio", ["j2"], {"j2_gear_ratio_rel": 0.002}),
    ({"a": {"j3": 0.8}}, "link_length", ["j3"], {"j3_a_mm": 0.8}),
    ({"sag": {"j2": 0.3, "j3": 0.2}}, "gravity_compliance", ["j2", "j3"],
     {"j2_compliance_deg_per_m": 0.3, "j3_compliance_deg_per_m": 0.2}),
])
def test_a_hidden_chain_effect_is_named_with_intervals_that_cover_it(tmp_path, effects, effect, joints, truth):
    # approach directions and temperatures recorded: a backlash or a thermal growth the
    # campaign can test is ruled out
    rep = diagnose_chain(read_campaign(chainsim.make(tmp_path / "c", effects, seed=3, dirs=True,
                                                     temps=True)), NOISE)
    assert rep["cause"]["effect"] == effect
    assert rep["cause"]["joints"] == joints
    assert not rep["unexplained"]
    assert rep["cause"]["confidence"] == "high", rep["cause"]["warnings"]
    assert rep["holdout"]["shrink"] > 0.6
    for name, v in truth.items():
        lo, hi = rep["cause"]["ci95"][name]
        assert lo < v < hi, name
    # registration is reported, and gap.rms_mm is the residual after it alone
    assert set(rep["registration"]["markers_mm"]) == {"1", "2", "3"}
    assert rep["gap"]["rms_mm"] == rep["registration"]["rms_mm"]
    # every candidate fit is full rank beside the registration, and says how well conditioned
    for entry in rep["ranking"]:
        assert entry["identifiable"] and entry["rank"] == entry["columns"] \
            == rep["registration"]["parameters"] + entry["k"]
        assert 1.0 <= entry["condition"] < 1e4, entry["label"]


def test_without_directions_an_untestable_backlash_stays_a_rival(tmp_path):
    # the same offsets without jK_dir columns: a backlash of j2 and j3 approached from one
    # side would show as these offsets, and nothing in the campaign can rule it out
    rep = diagnose_chain(read_campaign(chainsim.make(
        tmp_path / "c", {"offset": {"j2": 0.05, "j3": -0.08}}, seed=3)), NOISE)
    c = rep["cause"]
    assert c["effect"] == "joint_offset" and c["joints"] == ["j2", "j3"] and not rep["unexplained"]
    assert c["confidence"] == "ambiguous"
    untested = [r for r in c["rivals"] if r.get("testable") is False]
    assert [(r["effects"], r["joints"]) for r in untested] == [(["backlash"], ["j2", "j3"])]
    assert untested[0]["why"].startswith("not testable: no jK_dir column")
    assert any(w.startswith("the cause may be backlash on j2, j3, which this campaign cannot "
                            "test") for w in c["warnings"])
    assert not c["separating_poses"]       # no pose can separate what the campaign cannot test


def test_an_untestable_effect_behind_one_part_of_a_two_effect_cause_is_a_rival_with_the_rest(tmp_path):
    # an offset of j2 beside a longer j3 link, no jK_dir columns: a backlash of j2 could stand
    # behind the offset, so the truth may be that backlash *with* the link; the rival says
    # so (the backlash alone is the other untestable entry, and the one warned about)
    rep = diagnose_chain(read_campaign(chainsim.make(
        tmp_path / "c", {"offset": {"j2": 0.05}, "a": {"j3": 0.8}}, seed=3, temps=True)), NOISE)
    c = rep["cause"]
    assert {(x["effect"], tuple(x["joints"])) for x in c["components"]} == \
        {("joint_offset", ("j2",)), ("link_length", ("j3",))}
    assert c["confidence"] == "ambiguous"
    untested = [(r["label"], r["effects"], r["joints"]) for r in c["rivals"] if r.get("testable") is False]
    assert untested == [("backlash on j2", ["backlash"], ["j2"]),
                        ("backlash on j2 + link_length on j3", ["backlash", "link_length"], ["j2", "j3"])]
    assert [w for w in c["warnings"] if w.startswith("the cause may be")] == [
        "the cause may be backlash on j2, which this campaign cannot test (no jK_dir column: the "
        "direction of the joint's last motion is not known): measure what it lacks and diagnose again"]


def test_conditioning_sees_a_combination_the_data_cannot_separate():
    import numpy as np

    from cell.diagnosis.chain.fit import conditioning
    J = np.random.default_rng(0).normal(size=(30, 4))
    rank, cols, cond = conditioning(J)
    assert (rank, cols) == (4, 4) and cond < 10
    J[:, 3] = 2.0 * J[:, 0] - J[:, 1]          # a fourth parameter seen only as a sum
    rank, cols, cond = conditioning(J)
    assert (rank, cols) == (3, 4) and cond > 1e6


def test_no_effect_is_none_and_registration_absorbs_the_base_offset(tmp_path):
    rep = diagnose_chain(read_campaign(chainsim.make(tmp_path / "c", {}, seed=4)), NOISE)
    assert rep["cause"]["effect"] == "none"
    assert not rep["unexplained"]
    # a first vertical axis under a fitted sensor frame, the last one under free markers
    assert "registration" in rep["not_identifiable"]["j1_offset_deg"]
    assert "registration" in rep["not_identifiable"]["j6_offset_deg"]


@pytest.mark.parametrize("effects, lens", [({"reach_sag": 2.0}, 0.0), ({"bump": {"j3": 0.15}}, 0.0),
                                            ({}, 2e-3)])
def test_effects_outside_the_vocabulary_are_not_a_confident_cause(tmp_path, effects, lens):
    rep = diagnose_chain(read_campaign(chainsim.make(tmp_path / "c", effects, seed=5, lens=lens)), NOISE)
    assert rep["unexplained"] or rep["cause"]["effect"] == "none", rep["cause"]


def test_a_sensor_scale_taken_for_longer_links_is_not_a_confident_cause(tmp_path):
    # a tracker's radial scale of 2.1e-3 /m was once named link_length (j2, j3, j5) with no
    # doubt (validation trial 21 at commit 161ec53); the instrument-scale rival predicts the
    # left-out poses as well, so whatever is named is not 'high'
    rep = diagnose_chain(read_campaign(chainsim.make(tmp_path / "c", {}, seed=21, lens=2.1e-3)),
                         NOISE)
    c = rep["cause"]
    assert c["effect"] == "none" or c["confidence"] != "high" or rep["unexplained"], c


def test_the_instrument_scale_warning_names_itself(tmp_path):
    rep = diagnose_chain(read_campaign(chainsim.make(tmp_path / "c", {}, seed=5, lens=3e-3,
                                                     dirs=True, temps=True)), NOISE)
    c = rep["cause"]
    assert c["effect"] == "link_length"          # what the links alone would make of it
    assert c["confidence"] == "low"
    assert any("scale error of the measuring instrument" in w for w in c["warnings"])


def test_a_campaign_split_is_used_and_holdout_rows_are_not_fitted(tmp_path):
    rep = diagnose_chain(read_campaign(chainsim.make(tmp_path / "c", {"offset": {"j3": 0.1}}, split=True)),
                         NOISE)
    assert rep["split"]["source"] == "campaign"
    assert rep["split"]["holdout_poses"] == 20 and rep["split"]["fit_poses"] == 40


def test_calibrated_dh_model_is_the_new_nominal(tmp_path):
    c = chainsim.make(tmp_path / "c", {"offset": {"j2": 0.2}, "a": {"j3": 1.0}}, seed=6)
    cal = calibrate_chain(read_campaign(c))
    assert cal.passed
    v = cal.fit.named()
    assert abs(v["j2_offset_deg"] - 0.2) < 0.01 and abs(v["j3_a_mm"] - 1.0) < 0.05
    idn = cal.report()["identifiability"]
    assert idn["rank"] == idn["columns"] == cal.fit.J.shape[1] and idn["condition"] > 1.0
    out = write_calibrated(cal, tmp_path / "cal")
    again = read_campaign(tmp_path / "c", out["model"])
    rep = diagnose_chain(again, NOISE)
    assert rep["gap"]["rms_mm"] == pytest.approx(cal.fit.rms, abs=2e-6)  # report rounds to 1 µm
    assert rep["cause"]["effect"] == "none"


def _cellctl(*args):
    return subprocess.run([sys.executable, "-m", "cell.cli", *args], capture_output=True, text=True,
                          timeout=120)


@pytest.mark.skipif(not TIAGO.is_dir(), reason="real data not present")
def test_tiago_diagnose_and_calibrate_from_the_command_line(tmp_path):
    r = _cellctl("diagnose", str(TIAGO), "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert rep["format"] == "cell-diagnosis/1"
    assert rep["registration"]["sensor_frame"] and len(rep["registration"]["markers_mm"]) == 4
    # published: joint offsets take a held-out session from 4.87 to 4.23 mm (shrink 0.131)
    assert rep["holdout"]["shrink"] >= 1 - 4.23 / 4.87
    assert rep["cause"]["effect"] in ("joint_offset", "link_length")
    # upstream judges the 3-4 mm left after calibration non-geometric: it must be flagged
    assert rep["unexplained"] is True
    out = tmp_path / "tiago-cal"
    # the held-out max gets worse (6.38 -> 9.61 mm): refused, then written only on purpose
    r = _cellctl("calibrate", "kinematics", str(TIAGO), "--json", "--out", str(out))
    assert r.returncode == 2 and "--accept-worse" in r.stderr and not out.exists()
    r = _cellctl("calibrate", "kinematics", str(TIAGO), "--json", "--out", str(out),
                 "--accept-worse")
    assert r.returncode == 0, r.stderr
    cal = json.loads(r.stdout)
    assert not cal["check"]["passed"] and cal["warning"]
    assert cal["holdout"]["shrink"] >= 1 - 4.23 / 4.87
    assert (out / "model.yaml").is_file() and (out / "tiago_arm_chain_calibrated.urdf").is_file()
    r = _cellctl("diagnose", str(TIAGO), "--model", str(out / "model.yaml"), "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["gap"]["rms_mm"] == pytest.approx(cal["fit"]["rms_after_mm"], rel=1e-5)


def test_calibrate_refuses_a_campaign_with_cell_options(tmp_path):
    c = chainsim.make(tmp_path / "c", {}, poses=20)
    r = _cellctl("calibrate", "kinematics", str(c), "--sim")
    assert r.returncode == 2 and "--sim: not with a CAMPAIGN" in r.stderr


def test_chain_command_options_refused_where_they_do_not_apply(tmp_path):
    c = chainsim.make(tmp_path / "c", {}, poses=20)
    log = tmp_path / "cell.sqlite"
    log.write_bytes(b"SQLite format 3\x00" + bytes(100))
    r = _cellctl("diagnose", str(log), "--model", str(c / "model.yaml"))
    assert r.returncode == 2 and "--model" in r.stderr and "only with a campaign directory" in r.stderr
    before = sorted(p.name for p in c.iterdir())
    r = _cellctl("calibrate", "kinematics", str(c), "--out", str(c))
    assert r.returncode == 2 and "would overwrite the campaign itself" in r.stderr
    assert sorted(p.name for p in c.iterdir()) == before


def test_calibrate_refuses_a_scara_campaign(tmp_path):
    d = tmp_path / "scara"
    d.mkdir()
    (d / "model.yaml").write_text("format: cell-measurements/1\nkinematics: scara\nl1_mm: 325\nl2_mm: 275\n")
    (d / "points.csv").write_text("sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n0,0,10,20,400,200\n1,1,30,40,300,200\n")
    r = _cellctl("calibrate", "kinematics", str(d))
    assert r.returncode == 2 and "a SCARA campaign; CAMPAIGN must be a chain" in r.stderr
    assert not (tmp_path / "scara-calibrated").exists()
