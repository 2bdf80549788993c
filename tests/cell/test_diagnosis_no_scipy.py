"""The diagnosis of a planar campaign loads no scipy (its import was most of the start-up
CPU of ``cellctl diagnose``): fits by :mod:`cell.numerics.lsq`, neighbours and eigen-decompositions
by numpy; nor ``numpy.ma`` (about 10 ms), which ``numpy.median`` and a plain ``numpy.unique``
import (:func:`cell.numerics.stats.median`, :func:`cell.numerics.stats.distinct`), nor
``numpy.random`` when the campaign's tables carry their split; nor PyYAML (a plainly written
model.yaml), :mod:`statistics` or the HTML page, for either kind of campaign. Asserted on
the modules loaded, never on time."""
import subprocess
import sys

from cell import effects as fx
from cell.measurements import write_campaign
from cell.sim.campaigns import Design, make_campaign


def test_the_diagnosis_of_a_planar_campaign_imports_no_scipy(tmp_path):
    truth = [fx.make_effect("backlash", ("j2",), {"j2_backlash_deg": 0.04})]
    d = write_campaign(make_campaign(truth, 7, Design(n_points=120)), tmp_path / "c")
    code = ("import sys\nfrom cell.measurements import read_campaign\n"
            "from cell.diagnosis.answer import diagnose_campaign\n"
            f"r = diagnose_campaign(read_campaign({str(d)!r})).report\n"
            "print(r['cause']['label'], sorted(m for m in sys.modules if m.startswith('scipy') "
            "or m in ('numpy.ma', 'numpy.random', 'yaml', 'statistics', 'cell.diagnosis.page')))")
    assert "split" in (d / "points.csv").read_text().splitlines()[0]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    # numpy.ma: what numpy.median and a plain numpy.unique load on their first call;
    # numpy.random: only a campaign without a split column draws one
    assert out.stdout.split(" ", 1)[1].strip() == "[]", out.stdout


def test_the_diagnosis_of_a_chain_campaign_loads_no_planar_replay(tmp_path):
    # the v1 figures of a planar campaign read as a chain need the planar replay; a chain
    # campaign's diagnosis must not pay for importing it (start-up is most of its CPU)
    from cell.truth.chain_campaign import make
    d = make(tmp_path / "c", {"offset": {"j2": 0.05}}, poses=30)
    code = ("import sys\nfrom cell.measurements import read_campaign\n"
            "from cell.diagnosis.answer import diagnose_campaign\n"
            f"r = diagnose_campaign(read_campaign({str(d)!r})).report\n"
            "print(r['cause']['label'], sorted(m for m in sys.modules if m.startswith('scipy') or m in "
            "('numpy.ma', 'yaml', 'statistics', 'cell.diagnosis.page', "
            "'cell.diagnosis.figures', 'cell.diagnosis.replay', "
            "'cell.diagnosis.delay', 'cell.diagnosis.chain.planar')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.rsplit(" ", 1)[1].strip() == "[]", out.stdout


def test_the_split_generator_made_on_first_draw_draws_as_the_seeded_one():
    import numpy as np

    from cell.measurements.campaign import SPLIT_SEED, SplitRng, drawn_fit
    lazy, eager = SplitRng(), np.random.default_rng(SPLIT_SEED)
    for n in (300, 6, 1):          # the points, then the moves, from one generator
        assert drawn_fit(n, lazy).tolist() == drawn_fit(n, eager).tolist()
