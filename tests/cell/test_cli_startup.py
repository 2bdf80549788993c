"""``cellctl --help`` costs little more than Python itself: building the parser and printing
the help of every command and sub-command imports none of the heavy libraries (the issue
measured 1.4 s CPU per call when ``build_parser`` pulled in scipy). Checked by what a fresh
interpreter has imported, never by wall time."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
HEAVY = ("numpy", "scipy", "pydantic", "structlog", "yaml", "cv2", "pymodbus", "can", "canopen", "cryptography",
         "matplotlib", "apscheduler", "lxml", "urdf_parser_py", "sqlite3", "paho", "psycopg",
         "asyncua")

PROBE = r"""
import argparse, contextlib, io, json, sys
import cell.cli

def helps(parser, path):
    out = [path]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out += helps(sub, path + [name])
    return out

paths = helps(cell.cli.build_parser(), [])
printed = 0
for path in paths:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        try:
            cell.cli.main(path + ["--help"])
        except SystemExit:
            pass
    printed += "usage:" in buf.getvalue()
print(json.dumps({"paths": [" ".join(p) for p in paths], "printed": printed,
                  "modules": sorted({m.split(".")[0] for m in sys.modules})}))
"""


def test_help_of_every_command_imports_no_heavy_library():
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout)
    # the probe really walked the commands: top level, each command, nested ones
    assert {"", "diagnose", "calibrate kinematics", "plan line", "recipe validate"} <= set(got["paths"])
    assert got["printed"] == len(got["paths"])
    assert sorted(set(HEAVY) & set(got["modules"])) == []


def test_a_bad_preset_is_refused_by_the_parser_with_the_known_names(capsys):
    from cell.cli import main
    with pytest.raises(SystemExit) as exc:
        main(["plan", "line", "--robot", "seed999", "--from", "400,0,-50,0", "--to", "300,0,-20,45"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "seed999" in err and "seed000" in err and "seed002" in err


def test_each_command_is_registered_by_the_module_the_cli_names_for_it():
    # main builds only that module's parser for a plainly named command (start-up CPU of
    # every cellctl run); the table must name every command and the module that adds it
    import argparse
    import importlib

    from cell.cli import COMMAND_MODULES, COMMAND_OF
    found = {}
    for name in COMMAND_MODULES:
        sub = argparse.ArgumentParser().add_subparsers()
        importlib.import_module(name).register(sub)
        found.update({command: name for command in sub.choices})
    assert found == COMMAND_OF


@pytest.mark.parametrize("argv, command", [
    (["diagnose", "d"], "diagnose"), (["--log-format", "json", "diagnose", "d"], "diagnose"),
    (["--log-level=INFO", "plan", "line"], "plan"), (["--help"], None), (["--version"], None),
    (["--log-f", "json", "diagnose", "d"], None), (["nonsense"], None), ([], None)])
def test_the_command_is_read_from_plain_arguments_only(argv, command):
    from cell.cli import command_named
    assert command_named(argv) == command


def test_a_command_parsed_alone_parses_as_with_every_command():
    from cell.cli import build_parser
    argv = ["--log-level", "INFO", "diagnose", "some/dir", "--json"]
    assert vars(build_parser("diagnose").parse_args(argv)) == vars(build_parser().parse_args(argv))


def test_the_cell_starts_without_scipy_optimize():
    # the cell's own modules (what cellctl run and serve import) leave scipy.optimize, 0.1 s
    # of start-up, to the camera calibration's distortion fit, the one caller that needs it
    probe = "import sys, cell.app, cell.sim.assembly; print('scipy.optimize' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "False"


def test_the_cellctl_process_leaves_what_it_made_to_reference_counting_at_exit():
    # cellctl's entry (the console script and python -m cell.cli) freezes the heap after the
    # command, so exiting does not pass the collector over it; main itself, which tests call
    # in a process that goes on, does not
    import tomllib
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["cellctl"] == "cell.cli:entry"
    probe = ("import gc, io, contextlib, sys; import cell.cli as c; sys.argv = ['cellctl', 'registers', "
             "'--format', 'csv']\nwith contextlib.redirect_stdout(io.StringIO()):\n    c.main(sys.argv[1:])\n"
             "before = gc.get_freeze_count()\nwith contextlib.redirect_stdout(io.StringIO()):\n    code = c.entry()\n"
             "print(code, before, gc.get_freeze_count() > 1000)")
    out = subprocess.run([sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["0", "0", "True"]
