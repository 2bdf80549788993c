"""Cell config: the shipped example loads; bad sections name file, line and field."""
from pathlib import Path

import pytest

from cell.config import CellConfig
from cell.errors import ConfigError

EXAMPLE = Path(__file__).resolve().parents[2] / "deploy" / "cell.yaml"


def test_shipped_example_is_valid():
    cfg = CellConfig.load(EXAMPLE)
    assert cfg.stations.interface == "socketcan" and cfg.stations.delays_s == "measure"
    assert cfg.robot.scara().g.l1_mm == 500.0 and cfg.sim is None


@pytest.mark.parametrize("old, new, words", [
    ("  port: 502 ", "  port: 70000 ", r":{line}: plc.port"),
    ("  heartbeat_ms: 100 ", "  heartbeat_ms: 1 ", r":{line}: stations.heartbeat_ms"),
    ("  preset: seed000 ", "  preset: puma560 ", r":{parent}: robot: .*unknown robot preset 'puma560'"),
    ("  tool_radius_mm: 3.0", "  tool_radius_mm: 3.0\n  tool_colour: red", r":{line2}: vision.tool_colour: unknown field"),
    ("format: cell-config/1", "format: cell-config/9", r":{line}: format"),
    ("    kind: circles\n", "    kind: chessboard\n", r"calibration\.board must be a circle grid"),
    ("    cols: 7\n", "    cols: 2\n", r":{line}: calibration\.board\.cols: must be an integer in \[3, 100\]"),
    ("  poses: 24 ", "  poses: 2 ", r":{line}: calibration.poses"),
    ("  allow: [192.168.10.20] ", "  allow: [192.168.10.300] ",
     r":{line}: plc.allow: .*allow\[0\]: '192.168.10.300' is not an address or network"),
    ("  allow: [192.168.10.20] ", "  allow: [] ", r"plc: .*listens on every interface and allow is empty"),
])
def test_bad_config_is_located(tmp_path, old, new, words):
    text = EXAMPLE.read_text()
    assert old in text
    line = text[:text.index(old)].count("\n") + 1
    bad = tmp_path / "cell.yaml"
    bad.write_text(text.replace(old, new, 1))
    with pytest.raises(ConfigError, match=words.format(line=line, line2=line + 1, parent=line - 1)) as exc:
        CellConfig.load(bad)
    assert str(bad) in str(exc.value)


def test_missing_and_garbage_files(tmp_path):
    with pytest.raises(ConfigError, match="cell config not found"):
        CellConfig.load(tmp_path / "nope.yaml")
    (tmp_path / "bin.yaml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="cannot read cell config"):
        CellConfig.load(tmp_path / "bin.yaml")
