"""How the server is asked for: the ``opcua`` config section or ``--opcua HOST:PORT``;
off unless asked (the main job, ``cellctl run --sim``, starts none)."""
import pytest

from cell.commands.run import load_config
from cell.config import CellConfig
from cell.errors import ConfigError
from cell.opcua.config import parse_address


def test_off_by_default_and_on_with_the_option_pki_in_the_projects_var():
    from cell import paths
    assert load_config(None, True).opcua is None
    cfg = load_config(None, True, opcua="0.0.0.0:4841")
    assert (cfg.opcua.host, cfg.opcua.port) == ("0.0.0.0", 4841)
    assert cfg.opcua.pki == str(paths.project("var/opcua"))


def test_a_config_section_is_validated_and_its_paths_are_the_files(tmp_path):
    f = tmp_path / "cell.yaml"
    f.write_text("format: cell-config/1\nopcua:\n  port: 4850\n  pki: pki\n")
    cfg = CellConfig.load(f)
    assert cfg.opcua.port == 4850 and cfg.opcua.pki == str(tmp_path / "pki")
    f.write_text("format: cell-config/1\nopcua:\n  prt: 4850\n")
    with pytest.raises(ConfigError, match="prt"):
        CellConfig.load(f)
    f.write_text("format: cell-config/1\nopcua:\n  port: 70000\n")
    with pytest.raises(ConfigError, match="port"):
        CellConfig.load(f)


@pytest.mark.parametrize("text", ["4840", "host:", "host:port", "h:99999"])
def test_a_bad_address_is_refused_with_an_example(text):
    with pytest.raises(ValueError, match="HOST:PORT"):
        parse_address(text)
    with pytest.raises(ConfigError, match="HOST:PORT"):
        load_config(None, True, opcua=text)


def test_an_address_without_host_is_loopback():
    assert parse_address(":0") == ("127.0.0.1", 0) and parse_address("[::1]:4840") == ("::1", 4840)
