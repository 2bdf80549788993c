"""``cellctl recipe``: list, show, validate, diff and schema; bad files give exit 2 and a located message."""


from cell.cli import main
from cell.cyclelog import CycleLog

from tests.cell.conftest import REPO_RECIPES


def test_list_and_show(rdir, capsys):
    assert main(["recipe", "--dir", str(rdir), "list"]) == 0
    out = capsys.readouterr().out
    assert "bracket-a" in out and "pin-b" in out and "INVALID" not in out
    assert main(["recipe", "--dir", str(rdir), "show", "pin-b"]) == 0
    assert "sha256" in capsys.readouterr().out
    assert main(["recipe", "--dir", str(rdir), "show", "nope"]) == 2


def test_validate_names_file_line_field(rdir, capsys):
    bad = rdir / "bracket-a.yaml"
    bad.write_text(bad.read_text().replace("number: 1", "number: 1000"))
    assert main(["recipe", "--dir", str(rdir), "validate"]) == 2
    out = capsys.readouterr().out
    assert f"{bad}:4: number: " in out and "pin-b.yaml: ok" in out
    assert main(["recipe", "--dir", str(rdir), "list"]) == 0
    assert "INVALID" in capsys.readouterr().out


def test_diff_against_last_activated_version(rdir, tmp_path, capsys):
    db = tmp_path / "cell.sqlite"
    log = CycleLog(db)
    text = (rdir / "pin-b.yaml").read_text()
    log.remember_recipe("pin-b", "h", text)
    assert main(["recipe", "--dir", str(rdir), "diff", "pin-b", "--db", str(db)]) == 0
    assert "no differences" in capsys.readouterr().out
    (rdir / "pin-b.yaml").write_text(text.replace("k: 16", "k: 8"))
    assert main(["recipe", "--dir", str(rdir), "diff", "pin-b", "--db", str(db)]) == 1
    out = capsys.readouterr().out
    assert "-  k: 16" in out and "+  k: 8" in out
    assert main(["recipe", "--dir", str(rdir), "diff", "bracket-a", "--db", str(db)]) == 2
    assert "never activated" in capsys.readouterr().err


def test_schema(tmp_path, capsys):
    out = tmp_path / "s.json"
    assert main(["recipe", "schema", "--out", str(out)]) == 0
    assert out.read_text() == (REPO_RECIPES / "recipe.schema.json").read_text()


def _cell_yaml(tmp_path, **stations) -> str:
    import yaml

    from cell.config import CellConfig
    cfg = CellConfig()
    st = cfg.stations.model_dump(mode="json")
    st.update(stations)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump({**cfg.model_dump(mode="json", exclude={"sim", "stations"}), "stations": st}))
    return str(path)


def test_validate_against_the_cells_stations_names_the_motion_field(rdir, tmp_path, capsys):
    recipe = rdir / "bracket-a.yaml"
    text = recipe.read_text()
    # drives that apply a set-point 0.5..2 ms after it arrives: T = 2 ms is too short for j4
    slow = _cell_yaml(tmp_path, delays_s=[0.0005, 0.001, 0.0015, 0.002])
    recipe.write_text(text.replace("segment_ms: 10 ", "segment_ms: 2  "))
    assert main(["recipe", "--dir", str(rdir), "validate", "--config", slow]) == 2
    out = capsys.readouterr().out
    line = next(i for i, s in enumerate(recipe.read_text().splitlines(), 1) if "segment_ms" in s)
    assert f"{recipe}:{line}: motion.segment_ms: " in out and "delay of j4" in out
    assert main(["recipe", "--dir", str(rdir), "validate"]) == 0      # fine on its own
    # SYNC asked of drives that cannot do it
    stations = _cell_yaml(tmp_path)
    import yaml
    cfg = yaml.safe_load(open(stations))
    cfg["stations"]["stations"][2]["supports_sync"] = False
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cfg))
    recipe.write_text(text.replace("sync: corrected ", "sync: sync      "))
    capsys.readouterr()
    assert main(["recipe", "--dir", str(rdir), "validate", "--config", str(tmp_path / "cell.yaml")]) == 2
    out = capsys.readouterr().out
    assert "motion.sync: the joint stations do not support SYNC" in out and f"{recipe}:" in out


def test_validate_refuses_two_recipes_with_one_number(rdir, capsys):
    """Probe: validate passed two recipes with the same number, which the controller then
    rejected."""
    text = (rdir / "bracket-a.yaml").read_text()
    twin = rdir / "twin.yaml"
    twin.write_text(text.replace("name: bracket-a", "name: twin"))
    assert main(["recipe", "--dir", str(rdir), "validate", str(twin)]) == 2
    out = capsys.readouterr().out
    assert f"{twin}:4: number: recipe number 1 is also used by {(rdir / 'bracket-a.yaml').resolve()}" in out
    assert main(["recipe", "--dir", str(rdir), "validate"]) == 2      # both files of the pair
    assert capsys.readouterr().out.count("is also used by") == 2


def test_validate_refuses_a_position_the_robot_cannot_reach(rdir, capsys):
    """Probe: validate passed a nominal position out of reach, which faulted 401 at run time."""
    path = rdir / "bracket-a.yaml"
    path.write_text(path.read_text().replace("[250.0, 930.0]", "[900.0, 930.0]"))
    assert main(["recipe", "--dir", str(rdir), "validate"]) == 2
    out = capsys.readouterr().out
    assert f"{path}:7: part.nominal_xy_mm: the nominal part position (900.0, 930.0) mm cannot be reached" in out
    assert "out of reach" in out
    path.write_text(path.read_text().replace("[900.0, 930.0]", "[0.0, 998.5]"))    # the rim leaves reach
    assert main(["recipe", "--dir", str(rdir), "validate"]) == 2
    assert "part.search_radius_mm: the search window's rim" in capsys.readouterr().out


def test_validate_names_the_line_of_bytes_that_are_not_text(rdir, capsys):
    """Probe: non-UTF-8 recipe bytes gave no line number."""
    path = rdir / "bracket-a.yaml"
    raw = path.read_bytes().replace(b"fiducial_radius_mm: 1.5", b"fiducial_radius_mm: 1.5 \xff")
    path.write_bytes(raw)
    assert main(["recipe", "--dir", str(rdir), "validate"]) == 2
    out = capsys.readouterr().out
    assert f"{path}:8: cannot read recipe: not UTF-8 text (byte 0xff at column 27" in out
    path.write_bytes(raw.replace(b" \xff", b"\x00"))
    assert main(["recipe", "--dir", str(rdir), "validate"]) == 2
    assert f"{path}:8: malformed YAML: character code 0x00 at column 26" in capsys.readouterr().out
