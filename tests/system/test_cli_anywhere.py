"""Every command works from any working directory (issue 13, item 1).

Defaults (``recipes/``, ``deploy/plants/default.yaml``, ``var/cell.sqlite``) are the
project's; paths written in a config are that file's; only paths typed on the command line
are the shell's. Before, ``cellctl run --sim`` from another folder stopped with
``deploy/plants/default.yaml: plant file not found``.
"""
from __future__ import annotations

import os
import subprocess
import sys

import pytest
import yaml

from tests.system.conftest import REPO


def cellctl(cwd, *args, timeout=300):
    env = dict(os.environ, PYTHONPATH=str(REPO))      # the package, not the folder, is the project
    return subprocess.run([sys.executable, "-m", "cell.cli", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_commands_run_from_another_folder(tmp_path):
    out = cellctl(tmp_path, "run", "--sim", "--cycles", "6", "--db", "run.sqlite")
    assert out.returncode == 0, out.stderr[-2000:]
    assert "6/6 cycles done" in out.stdout
    assert (tmp_path / "run.sqlite").is_file()        # --db as typed: the shell's folder
    assert not (tmp_path / "var").exists()

    out = cellctl(tmp_path, "report", "--db", "./run.sqlite", "--png", "acc.png")
    assert out.returncode == 0, out.stderr
    assert (tmp_path / "acc.png").is_file()

    out = cellctl(tmp_path, "diagnose", "run.sqlite", "--json")
    assert out.returncode == 0, out.stderr[-2000:]

    out = cellctl(tmp_path, "recipe", "list")        # the project's recipes/
    assert out.returncode == 0, out.stderr
    assert "bracket-a" in out.stdout

    out = cellctl(tmp_path, "registers")
    assert out.returncode == 0 and "heartbeat" in out.stdout, out.stderr


def test_paths_in_a_config_are_the_config_files(tmp_path):
    """A relative path written in a config is taken from the config's folder; a key it
    leaves out (here the plant and the recipes) keeps the project's default."""
    conf = tmp_path / "conf"
    conf.mkdir()
    (conf / "cell.yaml").write_text(yaml.safe_dump({"sim": {"seed": 3}, "plc": {"host": "127.0.0.1"},
                                                    "log": {"path": "logs/cell.sqlite"}}))
    (conf / "logs").mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = cellctl(elsewhere, "run", "--sim", "--config", "../conf/cell.yaml", "--cycles", "1")
    assert out.returncode == 0, out.stderr[-2000:]
    assert (conf / "logs" / "cell.sqlite").is_file()
    assert list(elsewhere.iterdir()) == []


def test_config_defaults_are_the_projects_and_written_paths_the_files(tmp_path):
    from cell.config import CellConfig
    path = tmp_path / "cell.yaml"
    path.write_text("sim: {}\nrecipes:\n  directory: my-recipes\ncamera: {backend: folder, path: frames}\n"
                    "log:\n  path: /abs/cell.sqlite\n")
    cfg = CellConfig.load(path)
    assert cfg.recipes.directory == str(tmp_path / "my-recipes")
    assert cfg.camera["path"] == str(tmp_path / "frames")
    assert cfg.sim.plant == str(REPO / "deploy/plants/default.yaml")
    assert cfg.log.path == "/abs/cell.sqlite"
    assert cfg.calibration.file == str(REPO / "var/robot-calibration.json")
    assert CellConfig().with_paths().vision.calibration == str(REPO / "var/calibration.json")


def test_dev_py_run_from_another_folder(tmp_path):
    out = subprocess.run([sys.executable, str(REPO / "dev.py"), "run", "--cycles", "1", "--db", "x.sqlite"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "1/1 cycles done" in out.stdout and (tmp_path / "x.sqlite").is_file()
