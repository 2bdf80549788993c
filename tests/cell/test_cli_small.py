"""Small things a new user met (issue 13): a traceback when the reader of the output goes
away, help cut mid-sentence, reST backticks in help."""
from __future__ import annotations

import subprocess
import sys

from cell.cli import build_parser
from tests.system.conftest import REPO


def test_a_reader_that_goes_away_ends_the_command_quietly():
    """Probe: ``cellctl diagnose … | head`` printed a BrokenPipeError traceback. Here the
    reader closes its end before the command writes anything."""
    proc = subprocess.Popen([sys.executable, "-m", "cell.cli", "registers"], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=60) == 141
    assert "Traceback" not in err and "BrokenPipe" not in err, err


def _helps(parser, path=()):
    yield path, parser.format_help()
    for action in parser._actions:
        choices = getattr(action, "choices", None)
        if isinstance(choices, dict):                      # sub-parsers
            for name, sub in choices.items():
                yield from _helps(sub, path + (name,))


def test_help_has_no_backticks_and_whole_sentences():
    helps = dict(_helps(build_parser()))
    assert len(helps) > 15
    assert [p for p, text in helps.items() if "``" in text] == []
    diag = " ".join(helps[("diagnose",)].split())
    assert "how far it shrinks on withheld rows (report format in cell/measurements.md)." in diag
