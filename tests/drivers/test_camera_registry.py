"""Backends are chosen by name and imported lazily."""
from __future__ import annotations

import subprocess
import sys

import pytest

from cell.errors import ConfigError
from drivers.camera import BACKENDS, backend_class, create, from_config


def test_names_map_to_classes():
    assert set(BACKENDS) == {"opencv", "folder", "sim"}
    for name in BACKENDS:
        assert backend_class(name).backend == name


def test_backends_are_imported_only_when_asked_for():
    code = ("import sys, drivers.camera as c; "
            "assert 'drivers.camera.sim' not in sys.modules; "
            "assert 'drivers.camera.opencv_capture' not in sys.modules; "
            "c.backend_class('folder'); "
            "assert 'drivers.camera.folder' in sys.modules and 'drivers.camera.sim' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_unknown_backend_names_the_choices():
    with pytest.raises(ConfigError, match=r"camera.backend: unknown backend 'gige' \(known: folder, opencv, sim\)"):
        create("gige")


def test_unknown_option_names_the_backend():
    with pytest.raises(ConfigError, match=r"camera backend 'folder': .*exposure"):
        create("folder", path="/tmp", exposure=3)


def test_from_config_section(tmp_path):
    cam = from_config({"backend": "folder", "path": str(tmp_path), "loop": True})
    assert cam.backend == "folder" and cam.loop
    sim = from_config({"backend": "sim", "optics": {"noise_sigma": 0.0},
                       "model": {"intrinsics": {"fx": 500.0, "fy": 500.0, "cx": 31.5, "cy": 23.5,
                                                "width": 64, "height": 48},
                                 "pose": {"height_mm": 500.0}}})
    with sim:
        assert sim.grab().image.shape == (48, 64)


@pytest.mark.parametrize("section", [{}, {"path": "/tmp"}, ["folder"]])
def test_bad_config_sections(section):
    with pytest.raises(ConfigError, match="backend"):
        from_config(section)
