"""``python3 dev.py run`` on a fresh clone builds ``.venv`` first: minutes in which it
printed nothing. It now says each step on stderr, and how long the build took.

A real build installs the pinned packages from the network; here ``dev.py`` (the real file,
copied) builds a project of its own kind that pip installs offline in seconds: a tiny
``pyproject.toml`` whose in-tree build backend writes the wheel, with ``PIP_NO_INDEX`` so
nothing is fetched. The project's own ``.venv`` is never touched.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.system.conftest import REPO

PYPROJECT = """\
[build-system]
requires = []
build-backend = "tinybackend"
backend-path = ["."]
"""

# a PEP 517/660 backend that needs nothing installed: the wheel is a zip written by hand
BACKEND = '''\
import base64, hashlib, os, zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
DIST = "tiny_cell-0"


def _wheel(directory, files):
    with open(os.path.join(HERE, "requires.txt")) as f:
        requires = "".join(f"Requires-Dist: {r}\\n" for r in f.read().split())
    info = DIST + ".dist-info/"
    files = dict(files)
    files[info + "METADATA"] = ("Metadata-Version: 2.1\\nName: tiny_cell\\nVersion: 0\\n"
                                "Provides-Extra: test\\n" + requires)
    files[info + "WHEEL"] = "Wheel-Version: 1.0\\nGenerator: tiny\\nRoot-Is-Purelib: true\\nTag: py3-none-any\\n"
    files[info + "entry_points.txt"] = "[console_scripts]\\ncellctl = tiny_cell:main\\n"
    record = []
    for path, text in files.items():
        data = text.encode()
        digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        record.append(f"{path},sha256={digest},{len(data)}")
    files[info + "RECORD"] = "\\n".join(record + [info + "RECORD,,"]) + "\\n"
    name = DIST + "-py3-none-any.whl"
    with zipfile.ZipFile(os.path.join(directory, name), "w") as z:
        for path, text in files.items():
            z.writestr(path, text)
    return name


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    with open(os.path.join(HERE, "tiny_cell.py")) as f:
        return _wheel(wheel_directory, {"tiny_cell.py": f.read()})


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    return _wheel(wheel_directory, {"tiny_cell.pth": HERE + "\\n"})
'''

COMMAND = 'import sys\n\ndef main():\n    print("tiny cellctl ran", sys.argv[1:])\n'


def clone(tmp_path: Path) -> Path:
    root = tmp_path / "clone"
    root.mkdir()
    shutil.copy2(REPO / "dev.py", root / "dev.py")
    (root / "pyproject.toml").write_text(PYPROJECT)
    (root / "tinybackend.py").write_text(BACKEND)
    (root / "tiny_cell.py").write_text(COMMAND)
    (root / "requires.txt").write_text("")
    return root


def dev_py(root: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PIP_", "VIRTUAL_ENV"))}
    env.update(PIP_NO_INDEX="1", PIP_DISABLE_PIP_VERSION_CHECK="1", PYTHONDONTWRITEBYTECODE="1")
    return subprocess.run([sys.executable, str(root / "dev.py"), *args], cwd=cwd, env=env,
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=110)


def said(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("dev.py: ")]


@pytest.mark.slow
def test_building_the_venv_says_each_step_and_how_long_it_took(tmp_path):
    root = clone(tmp_path)
    out = dev_py(root, tmp_path, "cellctl", "hello")
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout == "tiny cellctl ran ['hello']\n"          # pip's output stays off stdout
    lines = said(out.stderr)
    assert len(lines) == 4, out.stderr
    assert "building" in lines[0] and "first run" in lines[0] and "minutes" in lines[0]
    assert "creating the virtual environment" in lines[1]
    assert "installing the pinned packages" in lines[2] and " s so far" in lines[2]
    assert lines[3].endswith(" s") and "ready in " in lines[3] and str(root / ".venv") in lines[3]

    again = dev_py(root, tmp_path, "cellctl", "hello")         # up to date: not a word
    assert again.returncode == 0 and said(again.stderr) == [] and again.stdout == out.stdout

    with (root / "pyproject.toml").open("a") as f:            # changed: reinstall, no new venv
        f.write("# changed\n")
    changed = dev_py(root, tmp_path, "cellctl")
    lines = said(changed.stderr)
    assert changed.returncode == 0, changed.stderr[-3000:]
    assert "pyproject.toml changed" in lines[0] and len(lines) == 3
    assert not any("creating" in line for line in lines)
    assert "installing the pinned packages" in lines[1] and "ready in " in lines[2]


@pytest.mark.slow
def test_a_failed_install_says_so_and_the_next_run_tries_again(tmp_path):
    """pip failing (no network, a package not found) ended dev.py in a CalledProcessError
    traceback."""
    root = clone(tmp_path)
    (root / "requires.txt").write_text("no-such-package-of-the-cell==1.0\n")
    out = dev_py(root, tmp_path, "cellctl", "hello")
    assert out.returncode != 0 and "tiny cellctl ran" not in out.stdout
    assert "Traceback" not in out.stderr and "CalledProcessError" not in out.stderr
    last = said(out.stderr)[-1]
    assert "pip install failed (exit " in last and "the next run tries again" in last
    assert not (root / ".venv" / ".cell-installed").exists()

    (root / "requires.txt").write_text("")
    fixed = dev_py(root, tmp_path, "cellctl", "hello")
    assert fixed.returncode == 0, fixed.stderr[-3000:]
    assert "an earlier build did not finish" in said(fixed.stderr)[0]
    assert fixed.stdout == "tiny cellctl ran ['hello']\n"
