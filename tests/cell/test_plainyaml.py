"""The plain YAML reader (:mod:`cell.measurements.plainyaml`) returns what
``yaml.safe_load`` returns, value for value and type for type, or gives up (None); and
the model files the project writes and ships are plain, so reading them imports no PyYAML."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from cell import effects as fx
from cell.measurements import write_campaign
from cell.measurements.plainyaml import plain_load
from cell.sim.campaigns import Design, make_campaign

REPO = Path(__file__).resolve().parents[2]


def same(a, b) -> bool:
    """Equal values of equal types, floats to the bit (the sign of zero included)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, float):
        return a == b and math.copysign(1.0, a) == math.copysign(1.0, b) or (a != a and b != b)
    return a == b


def agrees(text: str) -> bool:
    """plain_load gives up on ``text`` or returns yaml.safe_load's value; True if it read it."""
    found = plain_load(text)
    if found is None:
        return False
    assert same(found, yaml.safe_load(text)), text
    return True


EDGES = [
    "a: 1", "a: -0", "a: +7", "a: 012", "a: 0x10", "a: 1_000", "a: 123456789012345678901",
    "a: 1.5", "a: -0.0", "a: 1.", "a: .5", "a: 1e5", "a: 1.0e5", "a: 1.0e+5", "a: -2.5E-3",
    "a: 01.5", "a: 1:20", "a: .inf", "a: .nan", "a: inf", "a: NaN",
    "a: yes", "a: No", "a: on", "a: OFF", "a: y", "a: n", "a: true", "a: null", "a: ~", "a:",
    "a: 2021-01-01", "a: b c", "a: b  c", "a: b: c", "a: b:c", "a: -b", "a: b #c", "a: 'b #c'",
    "a: 'x'", "a: ''", 'a: "x"', 'a: "x\\ty"', 'a: "a: b"', "a: 'it''s'", "a: \"it's\"",
    "a: [1, 2]", "a: []", "a: [1, 2,]", "a: [a, [b]]", "a: {b: 1, c: x}", "a: {}", "a: {b: [1]}",
    "a: {b:1}", "a: {b: }", "a: [1,\n  2]", "yes: 1", "null: 1", "on: 2", "_k: v", "K9: v",
    "a: 1\na: 2", "a: 1\n b: 2", "a: b\n  c", "a:\n  b: 1\n  c: 2", "a:\n- 1\n- 2\nb: 3",
    "a:\n  - - 1\n    - 2\n  - 3", "- 1\n- 2", "a:\n  - b: 1\n    c: 2\n  - b: 3",
    "a:\n  - b: 1\n     c: 2", "a:\n  -  1", "a:\n  -\n    - 1", "a:\n  - 1\n   - 2",
    "# head\na: 1\n\n# mid\nb: [x, y]\n", "a: 1 # c", "---\na: 1", "a: 1\n...", "%YAML 1.1\n---\na: 1",
    "a: &x 1\nb: *x", "a: !!float 1", "a: |\n  text", "a: >\n  text", "? a\n: 1", "a:\tb",
    "a: 1\r\nb: 2", "a: é", "a: 1 ", "a: \x07", "\ufeffa: 1", "", "   ", "# only", "a",
    "a: [b c, d-e/f.g]", "a: {b: c d}", "a: [+1, -1, 0.0, -0.0]", "a: 99999999999999999999",
]


@pytest.mark.parametrize("text", EDGES)
def test_edge_cases_agree_or_give_up(text):
    agrees(text)


def test_plain_texts_are_read():
    assert plain_load("a: 1\nb:\n- - -170.0\n  - 170.0\nc: {d: x, e: '1'}\nf: \"g: h\"\n") == \
        {"a": 1, "b": [[-170.0, 170.0]], "c": {"d": "x", "e": "1"}, "f": "g: h"}


def _random_doc(rng, depth=0):
    def scalar():
        kind = rng.integers(6)
        if kind == 0:
            return int(rng.integers(-10 ** 6, 10 ** 6))
        if kind == 1:
            return float(rng.choice([0.0, -0.0, 1e-5, 1e20, 2.5e-300, 1.7976931348623157e308]))
        if kind == 2:
            return float(rng.normal(0, 10.0 ** rng.integers(-8, 9)))
        if kind == 3:
            return str(rng.choice(["x", "j1", "cell-measurements/1", "dh", "a b", "yes", "012",
                                   "1.5", "null", "", "it's", "a: b", "#", "-", "x-y_z.w/v"]))
        if kind == 4:
            return bool(rng.integers(2))
        return None
    if depth > 2 or rng.random() < 0.3:
        return scalar()
    if rng.random() < 0.5:
        return [_random_doc(rng, depth + 1) for _ in range(rng.integers(0, 4))]
    return {f"k{i}_{rng.integers(100)}": _random_doc(rng, depth + 1) for i in range(rng.integers(0, 4))}


def test_random_documents_agree_in_block_and_flow_style():
    rng = np.random.default_rng(3)
    read = 0
    for n in range(1500):
        doc = {f"key{i}": _random_doc(rng) for i in range(rng.integers(1, 5))}
        for style in (False, None):
            read += agrees(yaml.safe_dump(doc, sort_keys=False, default_flow_style=style))
    assert read > 600                    # most are plain: the reader is not a no-op


def test_written_models_are_plain_and_shipped_ones_agree(tmp_path):
    from cell.truth.chain_campaign import make
    for f in [*REPO.glob("tests/data/real/*/model.yaml"), *REPO.glob("cell/robots/*.yaml")]:
        agrees(f.read_text(encoding="utf-8"))         # hand-written: inline comments give up
    written = [write_campaign(make_campaign([fx.make_effect("backlash", ("j2",),
                                                            {"j2_backlash_deg": 0.04})],
                                            1, Design(n_points=30)), tmp_path / "p"),
               make(tmp_path / "c", {"offset": {"j2": 0.05}}, poses=20)]
    for d in written:
        assert agrees((d / "model.yaml").read_text(encoding="utf-8")), d


def test_reading_a_written_campaign_imports_no_pyyaml(tmp_path):
    d = write_campaign(make_campaign([], 2, Design(n_points=30)), tmp_path / "p")
    code = ("import sys\nfrom cell.measurements import read_campaign\n"
            f"read_campaign({str(d)!r})\nprint('yaml' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
