"""``cellctl diagnose validate`` on the independent truth: campaigns come from cell/truth (not
cell/effects) through files, effects outside the vocabulary get no confident cause, the
tables add up. Small seeded runs (120 poses) to keep the suite fast; the accuracy the
validation measures is asserted in tests/cell/test_validation_accuracy.py."""
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from cell import effects as fx
from cell.diagnosis import validate
from cell.truth import campaign, model, parts
from cell.truth.campaign import Design


def test_campaigns_do_not_go_through_effects_py():
    """Every Python function a campaign runs, as the interpreter's profile hook sees it
    (``sys.setprofile``): none is in cell/effects.py, while the truth's own model is."""
    truth = [parts.draw(np.random.default_rng(0), "backlash", 2)]
    ran: set[tuple[Path, str]] = set()

    def seen(frame, event, arg):
        if event == "call":
            ran.add((Path(frame.f_code.co_filename).resolve(), frame.f_code.co_name))
    before = sys.getprofile()
    sys.setprofile(seen)
    try:
        c = campaign.make_campaign(truth, 3, Design(n_points=30, n_moves=2))
    finally:
        sys.setprofile(before)
    assert (Path(model.__file__).resolve(), "joint_angle_deg") in ran    # the hook saw the truth run
    effects_dir = Path(fx.__file__).resolve().parent          # the cell/effects package
    assert sorted(name for f, name in ran if f.parent == effects_dir) == []
    assert len(c.points["x_mm"]) == 30 and len(set(c.paths["move"].tolist())) == 2


def test_outside_trials_come_from_their_own_stream():
    draws = [validate.draw_outside(s, 0.5, validate.OUTSIDE) for s in range(200)]
    assert 60 < sum(d is not None for d in draws) < 140
    assert all(validate.draw_outside(s, 0.0, validate.OUTSIDE) is None for s in range(50))
    assert all(validate.draw_outside(s, 1.0, ("reach_sag",)).kind == "reach_sag"
               for s in range(50))
    assert validate.draw_outside(7, 0.5, validate.OUTSIDE) == \
        validate.draw_outside(7, 0.5, validate.OUTSIDE)


def test_expected_answer_is_a_valid_vocabulary_instance():
    rng = np.random.default_rng(4)
    for k in parts.VOCABULARY:
        e = validate.expected(parts.draw(rng, k))
        assert e.effect == k and set(e.params) == set(e.param_names)
    with pytest.raises(ValueError, match="outside the vocabulary"):
        validate.expected(parts.draw(rng, "reach_sag"))


def test_combos_second_effect_is_smaller():
    d = Design(n_points=60, n_moves=2)
    for s in range(4):
        rows = campaign.draw_rows(s, d)
        main, second = validate.draw_truth(np.random.default_rng(s), True, rows, d)
        assert main.kind != second.kind
        assert campaign.rms_displacement([second], rows, d) <= \
            1.0 * campaign.rms_displacement([main], rows, d) + 1e-12


@pytest.fixture(scope="module")
def outside_run():
    """Two trials of each effect outside the vocabulary, plus a few vocabulary ones."""
    ts = []
    for k, kind in enumerate(validate.OUTSIDE):
        ts += validate.run(2, 30 + k, points=120, outside_share=1.0, outside_kinds=(kind,))
    return ts + validate.run(3, 5, points=120)


def test_outside_effects_get_no_confident_cause(outside_run):
    odd = [t for t in outside_run if t.outside]
    assert sorted({t.true_effect for t in odd}) == sorted(validate.OUTSIDE)
    named = [(t.true_effect, t.named) for t in odd if t.confident_cause]
    assert not named, named
    s = validate.summarise(outside_run)
    k = 2 * len(validate.OUTSIDE)
    assert s["outside_trials"] == len(odd) == k and s["trials"] == k + 3
    assert s["outside_named_as_cause"] + s["outside_unexplained"] + s["outside_none"] == k
    assert sum(s["outside_verdicts"].values()) == k and s["outside_verdicts"]["wrong"] == 0


def test_confusion_matrix_counts_add_up(outside_run):
    md = validate.markdown(outside_run, "t")
    lines = md.splitlines()
    start = lines.index("| true \\ answer | " + " | ".join(
        c.replace("_", " ") for c in list(validate.TRUTHS) + ["unexplained"]) + " |")
    table = lines[lines.index("| true effect | trials | named right | right joints | median shrink "
                              "| CI coverage | median CPU s |") + 2:start]
    per_effect = {m.group(1): int(m.group(2)) for m in
                  (re.match(r"\| (\w+(?: \(outside\))?) \| (\d+) \|", ln) for ln in table) if m}
    rows = {}
    for ln in lines[start + 2:]:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        rows[cells[0]] = sum(int(c) for c in cells[1:] if c != "·")
    assert sum(rows.values()) == len(outside_run) == sum(per_effect.values())
    for name, n in per_effect.items():
        assert rows[name.replace("_", " ")] == n
    for kind in validate.OUTSIDE:
        assert rows[kind.replace("_", " ") + " (outside)"] == 2
    head = next(i for i, ln in enumerate(lines) if ln.startswith("| trials | effect acc."))
    summary = lines[head + 2].strip("|").split("|")
    k = 2 * len(validate.OUTSIDE)
    assert summary[0].strip() == str(k + 3) and summary[-1].strip().endswith(f"/{k}")
    verdicts = [ln for ln in lines if ln.startswith("| planar, ")]
    assert sum(int(ln.split("|")[2]) for ln in verdicts) == k + 3


def test_run_refuses_bad_outside_settings():
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        validate.run(1, 0, outside_share=1.5)
    with pytest.raises(ValueError, match="unknown kinds"):
        validate.run(1, 0, outside_share=0.5, outside_kinds=("lens",))
    with pytest.raises(ValueError, match="unknown layout"):
        validate.run(1, 0, layout="grid")


def test_cyclic_error_counts_as_right_only_with_its_order():
    p = parts.Part("cyclic_error", 2, {"cycles": 3, "cos_deg": 0.02, "sin_deg": 0.01})
    truth = validate.expected(p)
    assert not validate._same_order(truth, {"j2_cyclic_amp_deg": 0.02})    # 360° by default
    assert validate._same_order(truth, {"j2_cyclic_period_deg": 120.0})
    assert not validate._same_order(truth, {"j2_cyclic_period_deg": 90.0})
    assert validate._same_order(validate.expected(parts.Part("backlash", 1, {"play_deg": 0.05})),
                                {})
    t = validate.Trial(0, "cyclic_error", ("j2",), False, "cyclic_error", ("j2",), False, "high",
                       0.9, 0, 0, 0.1, "wrong", "cyclic_error[j2]", "cyclic_error[j2]",
                       order_ok=False)
    assert t.effect_ok and not t.joint_ok


def test_a_low_confidence_cause_is_not_a_confident_one():
    def trial(named, unexplained, confidence):
        return validate.Trial(0, "reach_sag", (), True, named, (), unexplained, confidence, 0.3,
                              0, 0, 0.1, "", "reach_sag (outside)", named)
    assert trial("camera_scale", False, "high").confident_cause
    assert trial("camera_scale", False, None).confident_cause
    assert not trial("camera_scale", False, "low").confident_cause
    assert not trial("camera_scale", True, "high").confident_cause
    assert not trial("none", False, None).confident_cause
