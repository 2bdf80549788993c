"""Measurement exchange format v1: round trip, and every bad input named by file, line, column."""
import numpy as np
import pytest

from cell.measurements import (FORMAT, Campaign, CampaignFormatError, ModelSpec, read_campaign,
                               write_campaign)

MODEL = f"""format: {FORMAT}
kinematics: scara
l1_mm: 325.0
l2_mm: 275.0
command_unit_deg: 0.01
joint_limits_deg: [[-132, 132], [-145, 145]]
camera:
  center_mm: [300.0, 150.0]
stations: [j1, j2]
"""
POINTS = """sample,time_s,j1_deg,j2_deg,x_mm,y_mm,j1_dir,j2_dir,temp_c,split,comment
0,0.0,10.0,20.0,500.1,100.2,1,-1,21.5,fit,anything
1,1.5,11.0,21.0,499.0,110.0,-1,1,21.6,holdout,
"""
PATHS = """move,time_s,j1_cmd_deg,j2_cmd_deg,x_mm,y_mm,split
0,0.0,10,20,500,100,fit
0,0.01,10.1,20.1,499.5,101,fit
"""


def make(tmp_path, model=MODEL, points=POINTS, paths=PATHS):
    d = tmp_path / "campaign"
    d.mkdir(exist_ok=True)
    (d / "model.yaml").write_text(model)
    if points is not None:
        (d / "points.csv").write_text(points)
    if paths is not None:
        (d / "paths.csv").write_text(paths)
    return d


def test_reads_the_spec_example(tmp_path):
    c = read_campaign(make(tmp_path))
    assert c.model.l1_mm == 325.0 and c.model.camera.center_mm == (300.0, 150.0)
    assert c.points["sample"].tolist() == [0, 1]
    assert c.points["j2_dir"].tolist() == [-1.0, 1.0]
    assert c.points["split"].tolist() == ["fit", "holdout"]
    assert "comment" not in c.points                     # unknown columns are ignored
    assert c.paths["move"].tolist() == [0, 0]
    assert c.station_order == ["j1", "j2"]


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    n = 50
    points = {"sample": np.arange(n), "time_s": rng.uniform(0, 100, n),
              "j1_deg": rng.uniform(-90, 90, n), "j2_deg": rng.uniform(10, 140, n),
              "x_mm": rng.normal(300, 50, n), "y_mm": rng.normal(0, 50, n),
              "j1_dir": rng.choice([-1.0, 1.0], n), "j2_dir": rng.choice([-1.0, 1.0], n),
              "split": np.array(["fit", "holdout"] * (n // 2), dtype=object)}
    c = Campaign(model=ModelSpec(format=FORMAT, l1_mm=325, l2_mm=275), points=points)
    back = read_campaign(write_campaign(c, tmp_path / "out"))
    assert back.model == c.model and back.paths is None
    for k, v in points.items():
        assert back.points[k].tolist() == v.tolist(), k
    write_campaign(c, tmp_path / "out")                  # replacing an existing campaign works
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


@pytest.mark.parametrize("points, line, column, words", [
    ("sample,time_s,j1_deg,j2_deg,x_mm\n0,0,1,2,3\n", 1, "y_mm", "missing required column"),
    ("sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n0,0,1,2,3,4\n1,0,1,abc,3,4\n", 3, "j2_deg", "not a number"),
    ("sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n0,0,1,2,3,nan\n", 2, "y_mm", "not a finite"),
    ("sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n0.5,0,1,2,3,4\n", 2, "sample", "whole number"),
    ("sample,time_s,j1_deg,j2_deg,x_mm,y_mm,j1_dir\n0,0,1,2,3,4,0\n", 2, "j1_dir", "direction"),
    ("sample,time_s,j1_deg,j2_deg,x_mm,y_mm,temp_c\n0,0,1,2,3,4,21\n1,1,3,2,3,4,294.15\n", 3,
     "temp_c", r"temperature 294.15 °C is outside -40 … 150 °C.*kelvin"),
    ("sample,time_s,j1_deg,j2_deg,x_mm,y_mm,split\n0,0,1,2,3,4,train\n", 2, "split", "'fit' or 'holdout'"),
    ("sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n0,0,1,2,3,4\n0,1,1,2,3,4\n", 3, "sample", "not unique"),
    ("sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n0,0,1,2,3\n", 2, None, "5 fields"),
    ("", 1, None, "empty file"),
    ("sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n", 2, None, "no data rows"),
])
def test_bad_points_are_located(tmp_path, points, line, column, words):
    with pytest.raises(CampaignFormatError, match=words) as exc:
        read_campaign(make(tmp_path, points=points, paths=None))
    assert exc.value.file.endswith("points.csv")
    assert exc.value.line == line and exc.value.column == column


@pytest.mark.parametrize("model, column, words", [
    ("format: cell-measurements/2\nl1_mm: 1\nl2_mm: 1\n", "format", "unknown format"),
    (f"format: {FORMAT}\nl1_mm: -1\nl2_mm: 1\n", "l1_mm", "greater than 0"),
    (f"format: {FORMAT}\nl1_mm: 1\nl2_mm: 1\nlink3: 2\n", "link3", "unknown field"),
    (f"format: {FORMAT}\nkinematics: puma\nl1_mm: 1\nl2_mm: 1\n", "kinematics", "unsupported"),
    ("format: [unclosed\n", None, "not valid YAML"),
    ("- just\n- a list\n", None, "mapping"),
])
def test_bad_model_is_located(tmp_path, model, column, words):
    with pytest.raises(CampaignFormatError, match=words) as exc:
        read_campaign(make(tmp_path, model=model))
    assert exc.value.file.endswith("model.yaml") and exc.value.column == column


def test_bad_model_line_is_named(tmp_path):
    with pytest.raises(CampaignFormatError, match=r"model.yaml, line 3, column 'l2_mm'"):
        read_campaign(make(tmp_path, model=f"format: {FORMAT}\nl1_mm: 1\nl2_mm: zero\n"))


def test_missing_files(tmp_path):
    with pytest.raises(CampaignFormatError, match="not a campaign directory"):
        read_campaign(tmp_path / "nope")
    d = make(tmp_path, points=None, paths=None)
    with pytest.raises(CampaignFormatError, match="neither points.csv nor paths.csv"):
        read_campaign(d)
    (d / "model.yaml").unlink()
    with pytest.raises(CampaignFormatError, match="needs model.yaml"):
        read_campaign(d)


def test_binary_garbage_is_rejected(tmp_path):
    d = make(tmp_path, paths=None)
    (d / "points.csv").write_bytes(b"\xff\xfe\x00garbage\x80")
    with pytest.raises(CampaignFormatError, match="not UTF-8"):
        read_campaign(d)


@pytest.mark.parametrize("sep, named", [(";", "';'"), ("\t", "a tab")])
def test_a_semicolon_or_tab_separated_file_names_its_separator(tmp_path, capsys, sep, named):
    """A spreadsheet export with ';' (or tabs) was reported as "missing required column
    'sample'", without a word about the separator (issue 13, item 3)."""
    points = POINTS.replace(",", sep)
    d = make(tmp_path, points=points, paths=None)
    with pytest.raises(CampaignFormatError) as err:
        read_campaign(d)
    msg = str(err.value)
    assert msg.startswith(f"{d / 'points.csv'}, line 1: the separator is {named} where ',' is required")
    assert "missing" not in msg
    # the command says the same, exit 2, and writes nothing
    from cell.cli import main
    before = sorted(p.name for p in tmp_path.rglob("*"))
    assert main(["diagnose", str(d), "--html", str(tmp_path / "html")]) == 2
    err_text = capsys.readouterr().err
    assert "points.csv, line 1: the separator is" in err_text and "Traceback" not in err_text
    assert sorted(p.name for p in tmp_path.rglob("*")) == before


def test_a_comma_separated_file_with_semicolons_in_a_field_is_read(tmp_path):
    d = make(tmp_path, points=POINTS.replace("anything", '"a;b"'), paths=None)
    assert read_campaign(d).points["sample"].tolist() == [0, 1]
