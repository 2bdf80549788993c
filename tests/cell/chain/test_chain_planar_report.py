"""The diagnosis of a planar campaign (read by :func:`cell.measurements.chain.planar_as_chain`)
carries the v1 report's keys with their v1 meaning (``cell/measurements.md``, "Format
version 1.3"): on five generated campaigns, against the reports the planar engine gave
before the one diagnosis replaced it, the figures that must agree compared, and every
planar key the report lacks in the documented list :data:`LEFT_OUT`. Tolerances: figures
of the same rows and the same nominal model to the report's rounding (1 µm); figures of
each engine's own fit of the same cause within 5 % (10 % for a remainder's rms, 20 % for
a noise estimate from it).

The planar engine's reports are ``tests/data/planar-engine-reports.json``: each campaign of
:data:`CAMPAIGNS` written by :func:`cell.sim.campaigns.make_campaign` (seed :data:`SEED`),
read back and diagnosed by ``cell.diagnosis.report.diagnose`` at commit 048ffad, the last
with the planar engine; ``source`` set to the campaign's name, the ranking cut to its first
three entries."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from cell import effects as fx
from cell.diagnosis.chain.report import diagnose_chain
from cell.diagnosis.text import render
from cell.measurements import read_campaign, write_campaign
from cell.measurements.chain import planar_as_chain
from cell.sim.campaigns import make_campaign

SEED = 5
CAMPAIGNS = {
    "backlash": [fx.make_effect("backlash", ("j2",), {"j2_backlash_deg": 0.04})],
    "comm_delay": [fx.make_effect("comm_delay", (), {"comm_delay_sigma_ms": 2.0})],
    "none": [],
    "thermal_drift": [fx.make_effect("thermal_drift", (), {"thermal_expansion_per_k": 2e-5})],
    "cyclic_error": [fx.make_effect("cyclic_error", ("j1",), {
        "j1_cyclic_amp_deg": 0.02, "j1_cyclic_phase_deg": 30.0, "j1_cyclic_period_deg": 180.0})],
}
#: planar report keys the chain report leaves out, each in cell/measurements.md (1.3)
LEFT_OUT = {
    "cause.test.delta_bic", "cause.test.pair_p_value", "cause.test.runner_up_margin_bic",
    "cause.selection.nominal_cv_rms",
    "search", "search.method", "search.screened", "search.full_fits", "search.outlier_rounds",
    "remainder.systematic_share", "remainder.path_noise_ratio", "remainder.point_noise_ratio",
    "noise.method",
    "cause.nuisance", "cause.nuisance.path_temp_c", "cause.nuisance.path_temp_c_ci95",
    "cause.cyclic_orders",
}
#: the v1 report itself (cell/measurements.md, "Diagnosis report")
V1 = {"format", "gap", "gap.rms_mm", "gap.max_mm", "gap.n", "gap.where", "gap.where.subsystem",
      "gap.where.joints", "gap.where.depends_on", "gap.where.summary", "ranking",
      "ranking[].effect", "ranking[].joints", "ranking[].params", "ranking[].holdout_rms_mm",
      "ranking[].score", "cause", "cause.effect", "cause.joints", "cause.params", "cause.ci95",
      "holdout", "holdout.n", "holdout.rms_before_mm", "holdout.rms_after_mm", "holdout.shrink",
      "unexplained"}
#: keys whose own keys are data (parameter names, sources), not the format's
DATA = {"params", "ci95", "not_identifiable", "cyclic_orders", "estimates", "table", "rivals",
        "separating_poses", "components", "marked"}


def keys(d, pre: str = "") -> set[str]:
    """Every key path of report ``d`` (``ranking[]`` for the ranking's entries)."""
    out = set()
    for k, v in d.items():
        p = f"{pre}.{k}" if pre else k
        out.add(p)
        if k in DATA:
            continue
        if isinstance(v, dict):
            out |= keys(v, p)
        elif k == "ranking":
            for e in v:
                out |= keys(e, "ranking[]")
    return out


PLANAR = Path(__file__).parents[2] / "data" / "planar-engine-reports.json"


@pytest.fixture(scope="module", params=sorted(CAMPAIGNS))
def both(request, tmp_path_factory):
    """(the planar engine's report, the one diagnosis's) of one generated campaign."""
    d = tmp_path_factory.mktemp(request.param)
    write_campaign(make_campaign(CAMPAIGNS[request.param], SEED), d)
    c = read_campaign(d)
    planar = json.loads(PLANAR.read_text(encoding="utf-8"))[request.param]
    return request.param, planar, diagnose_chain(planar_as_chain(c, d))


def test_the_chain_report_has_every_v1_key_and_lacks_only_the_documented_ones(both):
    _, p, c = both
    assert c["chain"]["planar"] is True
    assert V1 <= keys(c)
    missing = keys(p) - keys(c)
    assert missing <= LEFT_OUT, sorted(missing - LEFT_OUT)
    assert c["format"] == p["format"] and c["format_version"] == p["format_version"] == "1.3"


def test_the_left_out_keys_are_documented():
    text = (Path(__file__).parents[3] / "cell" / "measurements.md").read_text(encoding="utf-8")
    section = text[text.index("## Format version 1.3"):]
    section = section[:section.index("\n# ")]
    for k in LEFT_OUT:
        assert f"`{k}`" in section or f"`{k.split('.')[-1]}`" in section, k


def test_the_gap_and_holdout_figures_are_the_planar_reports(both):
    _, p, c = both
    for t in ("points", "paths"):            # the same rows, the same nominal model
        assert c["gap"][t]["n"] == p["gap"][t]["n"]
        assert c["gap"][t]["rms_mm"] == pytest.approx(p["gap"][t]["rms_mm"], abs=2e-6)
        assert c["gap"][t]["max_mm"] == pytest.approx(p["gap"][t]["max_mm"], abs=2e-6)
        h, hp = c["holdout"][t], p["holdout"][t]
        assert h["n"] == hp["n"]
        assert h["rms_before_mm"] == pytest.approx(hp["rms_before_mm"], abs=2e-6)
        # each engine's own fit of the same cause: within 5 % (or a micrometre)
        assert h["rms_after_mm"] == pytest.approx(hp["rms_after_mm"], rel=0.05, abs=1e-3)
    assert (c["gap"]["n"], c["gap"]["rms_mm"], c["gap"]["max_mm"]) == pytest.approx(
        (p["gap"]["n"], p["gap"]["rms_mm"], p["gap"]["max_mm"]), abs=2e-6)
    assert c["gap"]["n"] == c["gap"]["points"]["n"] + c["gap"]["paths"]["n"]
    assert (c["holdout"]["n"], c["holdout"]["rms_before_mm"]) == (p["holdout"]["n"], p["holdout"]["rms_before_mm"])
    assert c["split"]["source"] == p["split"]["source"]
    assert c["spread"] == p["spread"]


def test_where_the_gap_lies_is_the_v1_analysis(both):
    _, p, c = both
    w, wp = c["gap"]["where"], p["gap"]["where"]
    assert w["depends_on"] == wp["depends_on"]
    assert set(w["effect_sizes"]) == set(wp["effect_sizes"])
    # outliers are each engine's own: the share the winning variable explains is within 0.05
    assert w["effect_sizes"][w["depends_on"]]["r2"] == pytest.approx(
        wp["effect_sizes"][wp["depends_on"]]["r2"], abs=0.05)
    for j in ("j1", "j2"):
        assert w["per_joint_rms_deg"][j] == pytest.approx(wp["per_joint_rms_deg"][j], rel=0.25, abs=5e-4)


def test_the_station_lags_agree_with_the_planar_engine(both):
    name, p, c = both
    dl, dp = c["delay"], p["delay"]
    assert (dl["detected"], dl["proportional"], dl["stations"], dl["moves"]) == \
        (dp["detected"], dp["proportional"], dp["stations"], dp["moves"])
    for j in ("j1", "j2"):
        assert dl["lags_ms"][j] == pytest.approx(dp["lags_ms"][j], abs=0.01)
    if name == "comm_delay":                 # σ = 2 ms: station k is 2·k ms late
        assert dl["sigma_ms"] == pytest.approx(2.0, abs=0.01) and dl["proportional"]


def test_noise_and_outliers_have_the_v1_shape(both):
    _, p, c = both
    nz, nzp = c["noise"], p["noise"]
    assert nz["path_sigma_mm"] == pytest.approx(nzp["path_sigma_mm"], abs=1e-7)
    assert nz["fit_rms_points_mm"] == pytest.approx(nzp["fit_rms_points_mm"], rel=0.1)
    assert nz["fit_rms_paths_mm"] == pytest.approx(nzp["fit_rms_paths_mm"], rel=0.1)
    assert set(nz["estimates"]) == set(nzp["estimates"])
    for src, e in nz["estimates"].items():
        assert e["source"] == src
        assert e["sigma_mm"] == pytest.approx(nzp["estimates"][src]["sigma_mm"], rel=0.2)
    o = c["outliers"]
    assert o["n"] == o["points"]["n"] + o["paths"]["n"] == len(o["marked"])
    for t in ("points", "paths"):
        assert set(o[t]) == set(p["outliers"][t])
        assert o[t]["n"] == len(o[t]["samples"])
    assert sorted(m["sample"] for m in o["marked"] if m["sample"] in o["points"]["samples"]) \
        == o["points"]["samples"]


def test_static_poses_and_move_samples_are_judged_for_outliers_each_on_their_own_scale(both):
    # a static arrival carries the arm's repeatability, a move's sample at its commanded
    # angles does not: with one scale for both, the samples' tighter spread made the static
    # poses' ordinary tail look like outliers (7-9 flagged on these clean campaigns, none
    # by the planar engine)
    _, p, c = both
    for t in ("points", "paths"):
        assert c["outliers"][t]["samples"] == p["outliers"][t]["samples"] == []
        assert c["outliers"][t]["sigma_mm"] == pytest.approx(p["outliers"][t]["sigma_mm"], rel=0.2)
        assert c["outliers"][t]["threshold_sigma"] == pytest.approx(p["outliers"][t]["threshold_sigma"],
                                                                    abs=0.05)
    assert c["outliers"]["points"]["sigma_mm"] > 1.5 * c["outliers"]["paths"]["sigma_mm"]


def test_a_gross_error_in_a_move_sample_is_still_set_aside(tmp_path):
    d = tmp_path / "c"
    camp = make_campaign([], SEED)
    camp.paths["x_mm"][300] += 0.5
    write_campaign(camp, d)
    o = diagnose_chain(planar_as_chain(read_campaign(d), d))["outliers"]
    assert o["points"]["n"] == 0 and o["paths"]["n"] == 1, o


def test_every_chain_ranking_entry_names_its_main_effect(both):
    _, _, c = both
    for e in c["ranking"]:
        assert e["effect"] == e["components"][0]["effect"] and e["effect"] in e["effects"]
        assert e["fit"] == "full"
        assert set().union(*(x["params"] for x in e["components"])) <= set(e["params"])


def test_the_cause_carries_the_v1_parameter_names_and_values(both):
    _, p, c = both
    assert c["cause"]["effect"] == p["cause"]["effect"]       # these campaigns: the same cause
    for n, v in p["cause"]["params"].items():
        assert c["cause"]["params"][n] == pytest.approx(v, rel=0.05, abs=1e-6), n
        lo, hi = c["cause"]["ci95"][n]
        assert lo <= c["cause"]["params"][n] <= hi


def test_the_text_shows_the_planar_sections(both):
    _, p, c = both
    heads = re.compile(r"^(gap: rms|effect sizes|per joint|comm lags:|holdout \(|noise:)", re.M)
    assert set(heads.findall(render(p))) <= set(heads.findall(render(c)))


def test_the_page_knows_every_v1_name_the_report_adds():
    # the page lists each fitted parameter once: every v1 name chain/planar.py adds beside a
    # chain parameter must be one page.V1_ALIAS recognises, and no chain parameter is
    from cell.diagnosis import page
    from cell.diagnosis.chain.planar import v1_params
    chain = {"j1_a_mm": 0.2, "j2_cyclic3_sin_deg": 0.01, "j2_cyclic3_cos_deg": -0.02,
             "j1_motor_cyclic_sin_deg": 0.003, "j1_offset_deg": 0.05}
    added, _ = v1_params(chain, {n: [v - 0.001, v + 0.001] for n, v in chain.items()})
    assert {"j1_link_delta_mm", "j2_cyclic_amp_deg", "j2_cyclic_phase_deg", "j2_cyclic_order",
            "j2_cyclic_period_deg", "j1_motor_cyclic_amp_deg", "j1_motor_cyclic_phase_deg"} == set(added)
    assert all(page.V1_ALIAS.search(n) for n in added)
    assert not any(page.V1_ALIAS.search(n) for n in chain)
    rep = {"chain": {"planar": True}, "cause": {"params": chain | added}}
    assert page.fitted(rep) == list(chain)
