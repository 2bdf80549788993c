"""A chain's ``model.yaml`` reads the same whether the plain path or pydantic judges it.

:mod:`cell.measurements.chain_spec` takes plainly valid input itself (``_plain_spec``,
``_plain_row``, ``_plain_coupling``: the fields, or None for "not plainly valid") and
leaves everything else to the pydantic models of ``pydantic_models()``. The input: every
chain model file of the repo (``cell/robots/*.yaml`` and the ``model.yaml`` of campaigns
under ``tests/data/``, kinematics dh or urdf), a richer version of each (coupling, tool,
markers, gravity, a prismatic joint, one without ``type``; a dh one also as urdf), 400
seeded variants of those with one to three faults each (a key dropped, added or renamed, a
value replaced by a string, a negative, zero, NaN, inf, 10**400, a bool, None, a wrong
literal, a list made longer, shorter, empty or a tuple, a mapping made a list), and every
single fault of a three-joint dh model, the same as urdf and the repo's urdf models
(some 6,000: a check that is wrong for one literal or one key is found too).

* whenever a plain check accepts, pydantic accepts and makes the same values (same types:
  float not int, tuple not list, -0.0 not 0.0);
* every entry point (``ChainSpec.model_validate``, ``ChainSpec(**kw)``, ``DHRow(**kw)``,
  ``Coupling(**kw)``, the reader's ``load_spec`` on a file) gives the same result, or the
  same error text, as it does with the plain checks switched off (pydantic alone).
"""
from __future__ import annotations

import copy
import functools
import math
import random
from pathlib import Path

import yaml
from pydantic import ValidationError

from cell.measurements import CampaignFormatError
from cell.measurements import chain as chain_reader
from cell.measurements import chain_spec as cs
from cell.measurements.chain_spec import ChainSpec, Coupling, DHRow
from cell.measurements.checked import pydantic_only

ROOT = Path(__file__).resolve().parents[2]
N_VARIANTS = 400
READ_EVERY = 4        # load_spec reads the repo's models and every 4th variant (YAML is slow)

# what a fault puts in a value's place, by kind
NUMBERS = [0, -1, -0.0, 1e308, 2 ** 53 + 1, 2 ** 64, -2 ** 63, 2 ** 1024, 10 ** 400, -10 ** 400,
           math.nan, math.inf, -math.inf]
STRINGS = ["", "1", "-2.5", " 3 ", "1e3", "nan", "inf", "abc", "j1", "from"]
LITERALS = ["standard", "modified", "Standard", "DH", "dh", "urdf", "scara", "revolute",
            "prismatic", "fixed", "continuous", "base", "sensor", "world", "unknown", "Unknown"]
OTHERS = [True, False, None, [], {}, [0, 0, 0], [1, 2], [1, "2", 3], [[0, 0, 1], [1, 2, 3]],
          {"x": 1}, {1: [0, 0, 1]}]
# what a key is replaced by or added as: unknown, misspelt, aliased, non-str, odd marker ids
KEYS = ["colour", "a_m", "Name", "from_", "from", "type", "limits", "tool", "1", 1, True, 1.0,
        -5, 10 ** 400, None]
FAULTS = ["drop", "add", "rekey", "number", "string", "literal", "other", "length", "tuple",
          "container"]


def chain_model_files() -> list[Path]:
    """Every chain model file of the repo: robots and the model.yaml of test campaigns."""
    files = sorted(ROOT.glob("cell/robots/*.yaml")) + sorted(ROOT.glob("tests/data/**/model.yaml"))
    return [f for f in files
            if (yaml.safe_load(f.read_text(encoding="utf-8")) or {}).get("kinematics") in cs.KINEMATICS]


def richer(model: dict) -> list[dict]:
    """Versions of ``model`` that use the optional keys too, a joint without ``type``
    and one prismatic (all plainly valid)."""
    out = copy.deepcopy(model)
    names = [j["name"] if isinstance(j, dict) else j for j in out["joints"]]
    out |= {"coupling": [{"joint": names[-1], "from": names[0], "factor": -0.5}],
            "tool_mm": [0, 0.0, 120], "gravity": [0, 0, 1], "measurement_frame": "sensor",
            "markers": {1: [0, 0, 50], 7: [10.5, -3, 50]}, "source": "variant"}
    if model["kinematics"] != "dh":
        return [out]
    out |= {"dh_convention": "modified", "urdf": None}
    out["joints"][0] |= {"type": "prismatic", "limits": [0, 500]}
    out["joints"][-1].pop("limits", None)
    out["joints"][len(out["joints"]) // 2].pop("type", None)   # the default
    as_urdf = copy.deepcopy(out) | {"kinematics": "urdf", "joints": names, "urdf": "arm.urdf",
                                    "base_link": "base", "tip_link": "tool0"}
    return [out, as_urdf]


def _nodes(x, path=()):
    """(path, node) of ``x`` and everything under it."""
    yield path, x
    items = x.items() if isinstance(x, dict) else enumerate(x) if isinstance(x, list) else ()
    for k, v in items:
        yield from _nodes(v, path + (k,))


def _sites(data: dict, kind: str) -> list[tuple[tuple, object]]:
    """(path, node) of every place in ``data`` a fault of ``kind`` can go."""
    nodes = list(_nodes(data))
    if kind in ("drop", "rekey"):
        return [(p, n) for p, n in nodes if isinstance(n, dict) and n]
    if kind == "add":
        return [(p, n) for p, n in nodes if isinstance(n, dict)]
    if kind in ("length", "tuple"):
        return [(p, n) for p, n in nodes if isinstance(n, list)]
    if kind == "string":
        return [(p, n) for p, n in nodes[1:] if not isinstance(n, (dict, list))]
    return nodes[1:]


def _args(node, kind: str) -> list:
    """What a fault of ``kind`` at ``node`` can put there or do."""
    values = {"number": NUMBERS, "string": STRINGS, "literal": LITERALS, "other": OTHERS}
    if kind in values:
        return values[kind]
    if kind == "drop":
        return list(node)
    if kind == "add":
        return [(k, v) for k in KEYS for v in (0, "x", None)]
    if kind == "rekey":
        return [(old, new) for old in node for new in KEYS]
    if kind == "length":
        return ["pop", "append", "clear"] if node else ["append"]
    return [None]


def _apply(data: dict, kind: str, path: tuple, arg) -> None:
    """Put the fault (``kind`` at ``path``, with ``arg`` of :func:`_args`) into ``data``."""
    parent = data
    for k in path[:-1]:
        parent = parent[k]
    node = parent[path[-1]] if path else data
    if kind == "drop":
        del node[arg]
    elif kind == "add":
        node[arg[0]] = arg[1]
    elif kind == "rekey":
        node[arg[1]] = node.pop(arg[0])
    elif kind == "length" and arg == "pop":
        node.pop()
    elif kind == "length" and arg == "append":
        node.append(copy.deepcopy(node[-1]) if node else 0.0)
    elif kind == "length":
        node.clear()
    elif kind == "tuple":                        # no YAML makes one, keyword arguments may
        parent[path[-1]] = tuple(node)
    elif kind == "container":                    # a mapping as a list, a list as a mapping
        parent[path[-1]] = list(node.values()) if isinstance(node, dict) else \
            dict(enumerate(node, 1)) if isinstance(node, list) else [node]
    else:
        parent[path[-1]] = copy.deepcopy(arg)


def _label(kind: str, path: tuple, arg) -> str:
    return f"{kind} {arg!r:.30} at {'.'.join(map(str, path)) or '(top)'}"


def _random_fault(data: dict, rnd: random.Random) -> str:
    """Put one fault of a random kind (:data:`FAULTS`) into ``data`` where it can go;
    returns what it did ("" if nowhere)."""
    kind = rnd.choice(FAULTS)
    sites = _sites(data, kind)
    if not sites:
        return ""
    path, node = rnd.choice(sites)
    arg = rnd.choice(_args(node, kind))
    _apply(data, kind, path, arg)
    return _label(kind, path, arg)


def every_single_fault(label: str, data: dict):
    """(label, variant) for every fault :func:`_sites` and :func:`_args` allow, one each."""
    for kind in FAULTS:
        for path, node in _sites(data, kind):
            for arg in _args(node, kind):
                out = copy.deepcopy(data)
                _apply(out, kind, path, arg)
                yield f"{label}: {_label(kind, path, arg)}", out


@functools.cache
def cases() -> list[tuple[str, dict]]:
    """(label, model) of the repo's chain models, their richer versions and the variants."""
    bases = []
    for f in chain_model_files():
        model = yaml.safe_load(f.read_text(encoding="utf-8"))
        bases += [(f.relative_to(ROOT).as_posix(), model)]
        bases += [(f"{f.name} richer {i}", m) for i, m in enumerate(richer(model))]
    rnd = random.Random(20261126)
    out = list(bases)
    for i in range(N_VARIANTS):
        label, data = rnd.choice(bases)
        data = copy.deepcopy(data)
        faults = [_random_fault(data, rnd) for _ in range(rnd.choice([1, 1, 1, 2, 2, 3]))]
        out.append((f"variant {i} of {label}: {'; '.join(filter(None, faults))}", data))
    return out


@functools.cache
def single_fault_cases() -> list[tuple[str, dict]]:
    """Every single fault of :func:`every_single_fault` in a richer dh model cut to three
    joints (the prismatic one, the one without ``type``, the last), the same as urdf, and
    each urdf model of the repo as it is."""
    models = [yaml.safe_load(f.read_text(encoding="utf-8")) for f in chain_model_files()]
    dh = next(m for m in models if m["kinematics"] == "dh")
    short = []
    for m in richer(dh):
        n = len(m["joints"])
        short.append(m | {"joints": [m["joints"][i] for i in sorted({0, n // 2, n - 1})]})
    bases = short + [m for m in models if m["kinematics"] == "urdf"]
    return [case for i, m in enumerate(bases) for case in every_single_fault(f"base {i}", m)]


def canon(x):
    """``x`` with every value's type spelt out (1 and 1.0, (1,) and [1], 0.0 and -0.0 differ)."""
    if isinstance(x, (ChainSpec, DHRow, Coupling)):
        return type(x).__name__, canon(vars(x))
    if isinstance(x, dict):
        return "dict", tuple((canon(k), canon(v)) for k, v in x.items())
    if isinstance(x, (list, tuple)):
        return type(x).__name__, tuple(canon(v) for v in x)
    if isinstance(x, float):
        return "float", x.hex()
    return type(x).__name__, x


def pydantic_alone(make, data) -> tuple:
    """What pydantic model ``make`` (0 ChainSpec, 1 DHRow, 2 Coupling) makes of ``data``,
    as the dataclass fields; or its error text."""
    try:
        m = cs.pydantic_models()[make].model_validate(data)
    except ValidationError as exc:
        return "refused", str(exc)
    if make == 0:
        return "ok", canon(ChainSpec._from_pydantic(m))
    return "ok", canon(dict(m))


def rows_and_terms(data) -> tuple[list, list]:
    """The joint rows and coupling terms of ``data`` that are mappings."""
    if not isinstance(data, dict):
        return [], []
    pick = lambda v: [x for x in v if isinstance(x, dict)] if isinstance(v, (list, tuple)) else []
    return pick(data.get("joints")), pick(data.get("coupling"))


def test_the_inputs_take_each_path():
    files = chain_model_files()
    assert any("robots" in f.parts for f in files) and len(files) >= 2, files
    labels = {label for label, _ in cases()}
    assert len(labels) == len(cases()) > N_VARIANTS           # entry_points keys by label
    # the repo's own models and their richer versions take the plain path
    for label, data in cases()[:len(cases()) - N_VARIANTS]:
        assert cs._plain_spec(data) is not None, label
    # the variants mix all three outcomes: plain, converted by pydantic, refused
    plain = converted = refused = 0
    for _, data in cases()[-N_VARIANTS:]:
        ok = pydantic_alone(0, data)[0] == "ok"
        is_plain = cs._plain_spec(data) is not None
        plain += is_plain
        converted += ok and not is_plain
        refused += not ok
    assert plain >= 40 and converted >= 10 and refused >= 150, (plain, converted, refused)


def test_what_the_plain_checks_accept_pydantic_accepts_unchanged():
    seen, bad = set(), []

    def check(label, what, make, plain_check, data):
        plain = plain_check(data)
        if plain is None or (key := (make, canon(data))) in seen:
            return
        seen.add(key)
        if ("ok", canon(plain)) != (pyd := pydantic_alone(make, data)):
            bad.append(f"{label}: {what} {data!r:.200}\n  plain    {canon(plain)}\n  pydantic {pyd}")
    for label, data in cases() + single_fault_cases():
        check(label, "model", 0, cs._plain_spec, data)
        rows, terms = rows_and_terms(data)
        for row in rows:
            check(label, "row", 1, cs._plain_row, row)
        for term in terms:
            check(label, "term", 2, cs._plain_coupling, term)
    assert len(single_fault_cases()) > 3000 and len(seen) > 1000, (len(single_fault_cases()), len(seen))
    assert not bad, f"{len(bad)} differ, e.g.\n" + "\n".join(bad[:5])


def outcome(make, *args, **kw) -> tuple:
    try:
        return "ok", canon(make(*args, **kw))
    except (ValidationError, CampaignFormatError, TypeError) as exc:
        return type(exc).__name__, str(exc)


def entry_points(files: dict[str, Path]) -> dict[tuple, tuple]:
    """The outcome of every way in, for every case: (label, entry point) -> outcome."""
    out = {}
    for label, data in cases():
        out[label, "model_validate"] = outcome(ChainSpec.model_validate, data)
        if isinstance(data, dict):
            out[label, "ChainSpec(**kw)"] = outcome(lambda: ChainSpec(**data))
        rows, terms = rows_and_terms(data)
        for i, row in enumerate(rows):
            out[label, f"DHRow(**kw) {i}"] = outcome(lambda: DHRow(**row))
        for i, term in enumerate(terms):
            kw = {"from_" if k == "from" else k: v for k, v in term.items()}
            out[label, f"Coupling(**kw) {i}"] = outcome(lambda: Coupling(**kw))
        if label in files:
            out[label, "load_spec"] = outcome(chain_reader.load_spec, files[label])
    return out


def test_every_entry_point_gives_what_pydantic_alone_gives(tmp_path):
    files = {}
    n_bases = len(cases()) - N_VARIANTS
    for n, (label, data) in enumerate(cases()):
        if n >= n_bases and (n - n_bases) % READ_EVERY:
            continue
        try:
            text = yaml.safe_dump(data, sort_keys=False)
        except yaml.representer.RepresenterError:  # a tuple: no file holds one
            continue
        files[label] = tmp_path / f"{n}.yaml"
        files[label].write_text(text, encoding="utf-8")
    with_plain = entry_points(files)
    with pydantic_only():
        alone = entry_points(files)
    assert with_plain.keys() == alone.keys()
    assert sum(k[1] == "load_spec" for k in alone) > N_VARIANTS // READ_EVERY * 3 // 4
    bad = [f"{key}:\n  plain    {with_plain[key]}\n  pydantic {alone[key]}"
           for key in alone if with_plain[key] != alone[key]]
    assert not bad, f"{len(bad)} differ, e.g.\n" + "\n".join(bad[:5])
