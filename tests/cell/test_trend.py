"""The accuracy trend picture (``cellctl report``'s PNG, :mod:`cell.cyclelog.trend`): checked on the
figure's artists, not its pixels."""
import numpy as np
import pytest

from cell.cli import main
from cell.cyclelog import CycleLog, CycleRecord
from cell.cyclelog.trend import Limits, plot_trend, rolling, tolerances, x_axis
from cell.recipes import content_hash

RECIPE = """name: {name}
number: {number}
part:
  nominal_xy_mm: [250.0, 933.0]
  fiducial_radius_mm: 2.0
verify:
  tolerance_mm: {tol}
"""


def _log(tmp_path, part_ids=None):
    """Two recipes (bracket-a at 0.08 then 0.06 mm, cover-b at 0.1 mm), part 7 faulted."""
    log = CycleLog(tmp_path / "cell.sqlite")
    texts = {k: RECIPE.format(name=n, number=i + 1, tol=t)
             for i, (k, n, t) in enumerate((("a1", "bracket-a", 0.08), ("a2", "bracket-a", 0.06),
                                            ("b", "cover-b", 0.1)))}
    for k, text in texts.items():
        log.remember_recipe(text.split("\n")[0][6:], content_hash(text), text)
    for i in range(30):
        key = "b" if i % 3 == 2 else ("a1" if i < 15 else "a2")
        log.add_cycle(CycleRecord(
            part_id=(part_ids[i] if part_ids else 500 + i), recipe="cover-b" if key == "b" else "bracket-a",
            recipe_hash=content_hash(texts[key]), status="fault" if i == 7 else "done",
            started_at=f"2026-11-23T10:{i:02d}:00+00:00", finished_at=f"2026-11-23T10:{i:02d}:40+00:00",
            cycle_time_s=1.0, initial_error_mm=0.3 + 0.01 * i, final_error_mm=0.02 + 0.001 * i,
            verify_error_mm=0.021 + 0.001 * i, moves=2))
    return log, texts


def test_rolling_mean_and_p95_over_a_trailing_window():
    m, p = rolling(np.arange(1.0, 11.0), window=4, min_periods=3)
    assert np.isnan(m[:2]).all() and m[2] == 2.0 and m[9] == pytest.approx(8.5)
    assert p[9] == pytest.approx(np.percentile([7, 8, 9, 10], 95))


def test_x_is_the_part_number_when_it_rises_else_the_time(tmp_path):
    log, _ = _log(tmp_path)
    xs, label = x_axis(log.cycles())
    assert xs[:2] == [500, 501] and label.startswith("part number")
    log2, _ = _log(tmp_path / "b", part_ids=[1, 2, 3] * 10)          # a PLC that restarts its count
    xs, label = x_axis(log2.cycles())
    assert label == "cycle finished at (UTC)" and xs[0].minute == 0 and xs[1].minute == 1


def test_figure_holds_tolerance_per_recipe_version_threshold_rolling_stats_and_faults(tmp_path):
    log, texts = _log(tmp_path)
    cycles = log.cycles()
    tol = tolerances(log, cycles)
    assert tol == {content_hash(texts["a1"]): 0.08, content_hash(texts["a2"]): 0.06,
                   content_hash(texts["b"]): 0.1}
    tp = plot_trend(cycles, Limits(tol, threshold_mm=0.45, window=6))
    a = tp.artists
    ya = a["tolerance:bracket-a"].get_ydata()
    assert set(ya) == {0.08, 0.06} and ya[0] == 0.08 and ya[-1] == 0.06   # the change shows
    assert set(a["tolerance:cover-b"].get_ydata()) == {0.1}
    assert list(a["threshold"].get_ydata()) == [0.45, 0.45]
    assert "0.45 mm" in a["threshold"].get_label()
    for name in ("bracket-a", "cover-b"):
        for kind in ("final_mean", "final_p95", "initial_mean", "final"):
            assert f"{kind}:{name}" in a
    assert len(a["faults"]) == 1 and a["faults"][0].get_xdata()[0] == 507
    assert "cycle id" not in tp.x_label and tp.x_label.startswith("part number")
    assert "bracket-a, cover-b" in tp.title and "2026-11-23 10:00 – 10:29 UTC" in tp.title
    axes = tp.fig.axes
    assert all("mm" in ax.get_ylabel() for ax in axes) and axes[1].get_xlabel() == tp.x_label


def test_unknown_recipe_version_draws_no_tolerance_but_says_so(tmp_path):
    log = CycleLog(tmp_path / "x.sqlite")
    for i in range(6):
        log.add_cycle(CycleRecord(part_id=i, recipe="r", recipe_hash="nohash", status="done",
                                  started_at="2026-11-23T10:00:00+00:00",
                                  finished_at=f"2026-11-23T10:00:0{i}+00:00", cycle_time_s=1.0,
                                  initial_error_mm=0.1, final_error_mm=0.01))
    cycles = log.cycles()
    assert tolerances(log, cycles, tmp_path / "no-such-dir") == {"nohash": None}
    tp = plot_trend(cycles, Limits({"nohash": None}))
    assert "tolerance:r" not in tp.artists
    labels = [t.get_text() for ax in tp.fig.axes for t in ax.get_legend().get_texts()]
    assert any("tolerance unknown" in t for t in labels)


def test_tolerance_from_the_recipe_folder_when_the_log_lacks_the_version(tmp_path):
    text = RECIPE.format(name="bracket-a", number=1, tol=0.07)
    (tmp_path / "recipes").mkdir()
    (tmp_path / "recipes" / "bracket-a.yaml").write_text(text)
    log = CycleLog(tmp_path / "x.sqlite")
    log.add_cycle(CycleRecord(part_id=1, recipe="bracket-a", recipe_hash=content_hash(text),
                              status="done", started_at="2026-11-23T10:00:00+00:00",
                              finished_at="2026-11-23T10:00:01+00:00", cycle_time_s=1.0))
    assert tolerances(log, log.cycles(), tmp_path / "recipes") == {content_hash(text): 0.07}


def test_report_command_writes_the_png_at_its_size_with_the_config_threshold(tmp_path, capsys):
    from PIL import Image
    log, _ = _log(tmp_path)
    cfg = tmp_path / "cell.yaml"
    cfg.write_text("scheduler:\n  drift_threshold_mm: 0.35\n  drift_window: 8\n")
    png = tmp_path / "trend.png"
    assert main(["report", "--db", str(log.path), "--png", str(png), "--config", str(cfg)]) == 0, \
        capsys.readouterr().err
    with Image.open(png) as im:
        assert im.size == (1100, 750)
