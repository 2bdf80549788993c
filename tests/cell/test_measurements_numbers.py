"""Numbers past what a float or an int64 holds, and YAML scalars PyYAML cannot make into a
value, are bad input like any other: a CampaignFormatError naming the file, line and key
(or column), never a bare OverflowError or ValueError. Which message each gets follows the
readers' rules (``cell/measurements/campaign.py`` docstring, ``cell/measurements.md``): in
model.yaml an int too large for a float is not a valid number (pydantic's word, as for a
chain's model.yaml); a CSV cell is read as a float, so a huge value there is infinite and
refused as not finite, except in an int column (sample, move, marker), which is read
exactly and must fit in 64 bits."""
import pytest
from pydantic import ValidationError

from cell.measurements import FORMAT, CampaignFormatError, ModelSpec, read_campaign
from cell.measurements import campaign as m
from tests.cell.chain import chainsim

BIG = "1" + "0" * 400                      # 10**400: an int, but no float
HUGE = "1" + "0" * 5000                    # past Python's int-from-text limit (4300 digits)
POINTS = "sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n1,0,10,20,1,2\n2,1,11,22,1,2\n"


def make(tmp_path, model: str, points: str = POINTS, paths: str | None = None):
    d = tmp_path / "c"
    d.mkdir(exist_ok=True)
    (d / "model.yaml").write_text(f"format: {FORMAT}\n" + model)
    (d / "points.csv").write_text(points)
    if paths is not None:
        (d / "paths.csv").write_text(paths)
    return d


def refused(d) -> CampaignFormatError:
    with pytest.raises(CampaignFormatError) as exc:
        read_campaign(d)
    return exc.value


@pytest.mark.parametrize("model, line, column", [
    (f"l1_mm: {BIG}\nl2_mm: 275\n", 2, "l1_mm"),
    (f"l1_mm: 325\nl2_mm: -{BIG}\n", 3, "l2_mm"),
    (f"l1_mm: 325\nl2_mm: 275\ncommand_unit_deg: {BIG}\n", 4, "command_unit_deg"),
    (f"l1_mm: 325\nl2_mm: 275\njoint_limits_deg:\n  - [-170, 170]\n  - [-150, {BIG}]\n", 6,
     "joint_limits_deg.1.1"),
    (f"l1_mm: 325\nl2_mm: 275\ncamera:\n  center_mm: [{BIG}, 0]\n", 5, "camera.center_mm.0"),
])
def test_an_int_too_large_for_a_float_in_model_yaml_is_located(tmp_path, model, line, column):
    err = refused(make(tmp_path, model))
    assert err.file.endswith("model.yaml") and (err.line, err.column) == (line, column)
    assert err.message == "must be a valid number"


def test_the_plain_check_leaves_an_int_too_large_for_a_float_to_pydantic():
    data = {"format": FORMAT, "l1_mm": int(BIG), "l2_mm": 275}
    assert m._number(int(BIG)) is None and m._plain(data) is None
    for make_spec in (ModelSpec.model_validate, lambda d: ModelSpec(**d)):
        with pytest.raises(ValidationError, match="valid number"):
            make_spec(data)
    assert m._number(2 ** 1023) == 2.0 ** 1023      # the largest powers of two still are floats


@pytest.mark.parametrize("model, line, column, words", [
    (f"l1_mm: {HUGE}\nl2_mm: 275\n", 2, "l1_mm", "Exceeds the limit (4300 digits)"),
    ("l1_mm: 325\nl2_mm: 275\ncamera:\n  center_mm: [0, 2021-13-01]\n", 5, "camera.center_mm.1",
     "month must be in 1..12"),
    ("l1_mm: 325\nl2_mm: !!float abc\n", 3, "l2_mm", "could not convert"),
    # a chain's model.yaml goes the same way (read_campaign decides the kind from it first)
    (f"kinematics: dh\njoints:\n  - {{name: j1, a_mm: 0, alpha_deg: 0, d_mm: {HUGE}, theta_deg: 0}}\n",
     4, "joints.0.d_mm", "Exceeds the limit"),
])
def test_a_scalar_yaml_cannot_make_is_located(tmp_path, model, line, column, words):
    err = refused(make(tmp_path, model))
    assert err.file.endswith("model.yaml") and (err.line, err.column) == (line, column)
    assert err.message.startswith("cannot be read: ") and words in err.message
    assert "set_int_max_str_digits" not in err.message


@pytest.mark.parametrize("cell, column, words", [
    (BIG, "x_mm", "not a finite number: '1000"),
    (BIG, "sample", "not a finite number: '1000"),
    ("1e400", "j1_deg", "(too large for a float)"),
    ("1e300", "sample", "whole number out of range"),
    (str(2 ** 63), "sample", "whole number out of range"),
    (str(-2 ** 63 - 1), "sample", "whole number out of range"),
    ("1e-400", "sample", "not a whole number"),
])
def test_a_huge_number_in_points_csv_is_located(tmp_path, cell, column, words):
    header = "sample,time_s,j1_deg,j2_deg,x_mm,y_mm"
    row = dict(zip(header.split(","), "2,1,11,22,1,2".split(",")), **{column: cell})
    err = refused(make(tmp_path, "l1_mm: 325\nl2_mm: 275\n",
                       f"{header}\n1,0,10,20,1,2\n{','.join(row.values())}\n"))
    assert err.file.endswith("points.csv") and (err.line, err.column) == (3, column)
    assert words in err.message


def test_an_int_column_is_read_exactly_to_64_bits(tmp_path):
    ids = [2 ** 53 + 1, 2 ** 53, 2 ** 63 - 1, -2 ** 63]     # a float makes the first two one
    body = "".join(f"{s},0,{10 + i},20,1,2\n" for i, s in enumerate(ids))
    c = read_campaign(make(tmp_path, "l1_mm: 325\nl2_mm: 275\n",
                           "sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n" + body))
    assert c.points["sample"].tolist() == ids


def test_a_huge_move_in_paths_csv_is_located(tmp_path):
    paths = f"move,time_s,j1_cmd_deg,j2_cmd_deg,x_mm,y_mm\n0,0,10,20,1,2\n{2 ** 64},0.1,11,21,1,2\n"
    err = refused(make(tmp_path, "l1_mm: 325\nl2_mm: 275\n", paths=paths))
    assert err.file.endswith("paths.csv") and (err.line, err.column) == (3, "move")
    assert "whole number out of range" in err.message


def test_a_huge_number_in_a_chain_campaign_is_located(tmp_path):
    d = chainsim.make(tmp_path / "chain", {}, poses=8, sensor=False)
    text = (d / "model.yaml").read_text()
    (d / "model.yaml").write_text(text.replace("a_mm: -425.0", f"a_mm: {BIG}", 1))
    err = refused(d)
    j2 = next(n for n, ln in enumerate(text.splitlines(), 1) if "name: j2" in ln)
    assert err.file.endswith("model.yaml") and (err.line, err.column) == (j2, "joints.1.a_mm")
    assert err.message == "joint 2 (column j2): must be a valid number"
    (d / "model.yaml").write_text(text)
    lines = (d / "points.csv").read_text().splitlines()
    header = lines[0].split(",")
    row = lines[3].split(",")
    row[header.index("marker")] = "1e300"
    (d / "points.csv").write_text("\n".join(lines[:3] + [",".join(row)] + lines[4:]) + "\n")
    err = refused(d)
    assert err.file.endswith("points.csv") and (err.line, err.column) == (4, "marker")
    assert "whole number out of range" in err.message
