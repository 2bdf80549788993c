"""The tables of the README and of docs/ are what their commands print
(bench/check_readme_tables.py).

Every command not marked ``slow`` is run here; the slow ones (bench_cell,
bench_calibration, the storm, soak and load benches, the ``--combos`` and
``--out-of-vocabulary`` diagnosis validations) only by the script:
``.venv/bin/python bench/check_readme_tables.py``. Deterministic tables (simulated time,
counts, accuracy) must match cell for cell outside their wall-time columns; wall-time
tables must keep their columns (from a short run of the command). A failure shows the
table's diff and the one command that re-prints it into the README.
"""
from __future__ import annotations

import importlib.util
import sys

import pytest

from tests.system.conftest import REPO

_spec = importlib.util.spec_from_file_location("check_readme_tables", REPO / "bench" / "check_readme_tables.py")
check = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = check            # dataclasses look their module up there
_spec.loader.exec_module(check)


def test_every_table_has_its_command_or_is_written_by_hand():
    texts = check.read_pages()
    homes = {s.name: check.home(s, texts) for s in check.SOURCES}   # each command above its tables
    left = [(path, t) for path, lines in texts.items()
            for t in check.uncovered(lines, [s for s in check.SOURCES if homes[s.name] == path])]
    assert not left, "tables no command in bench/check_readme_tables.py prints:\n" + "\n".join(
        f"{check.shown(path)}:{t.start + 1}: {t.lines[0]}" for path, t in left)


def test_a_changed_figure_is_found_and_shown():
    """The check itself: a README whose figure differs from the printed one is reported
    with a diff naming both; a wall-time cell that differs is not."""
    source = check.Source("demo", "demo cmd", ("demo",), 1, (check.cols("ms"),))
    readme = ["`demo cmd` printed:", "", "| case | error mm | ms |", "|---|---:|---:|",
              "| a | 0.0265 | 0.44 |", "| b | 5.7e-14 | 0.50 |"]
    same = ["| case | error mm | ms |", "|---|---:|---:|", "| a | 0.0265 | 9.99 |", "| b | 0.0e+00 | 1 |"]
    [ok] = check.compare(source, same, readme, full=True)
    assert ok.problem == ""                        # wall time and float noise are not figures
    changed = ["| case | error mm | ms |", "|---|---:|---:|", "| a | 0.0300 | 0.44 |", "| b | 0 | 1 |"]
    [bad] = check.compare(source, changed, readme, full=True)
    assert bad.problem == "figures differ" and bad.readme_line == 3
    assert "-| a | 0.0265 | 0.44 |" in bad.diff and "+| a | 0.0300 | 0.44 |" in bad.diff
    other = ["| case | error |", "|---|---|", "| a | 1 |"]
    [gone] = check.compare(source, other, readme, full=True)
    assert gone.problem == "the command prints no table with these columns"


#: the tables whose commands take 3 s or more: the slow tier (tests/conftest.py)
LONG = {"can", "validate", "chain", "chain-oov", "vision", "cell-latency", "diagnose-cpu", "scan",
        "load-main", "diagnosis-speed", "chain-speed", "opcua-scan", "plant"}


@pytest.mark.timeout(900)
@pytest.mark.parametrize("name", [pytest.param(s.name, marks=pytest.mark.slow) if s.name in LONG
                                  else s.name for s in check.SOURCES if not s.slow])
def test_readme_tables_match_what_their_command_prints(name):
    source = next(s for s in check.SOURCES if s.name == name)
    texts = check.read_pages()
    page = check.home(source, texts)
    findings, _, ran = check.check(source, texts[page], use_probe=True, timeout=800)
    bad = [f for f in findings if f.problem]
    assert not bad, "\n\n".join(f"{check.shown(page)}:{f.readme_line}: {f.problem} (`{' '.join(ran)}`)\n{f.diff}"
                                for f in bad) + \
        f"\n\nIf the change is meant, re-print: .venv/bin/python bench/check_readme_tables.py --only {name} --update"
