"""Shared fixtures of the cell tests."""
import shutil
from pathlib import Path

import pytest

REPO_RECIPES = Path(__file__).resolve().parents[2] / "recipes"


@pytest.fixture
def rdir(tmp_path):
    """A private copy of the shipped recipes directory."""
    d = tmp_path / "recipes"
    shutil.copytree(REPO_RECIPES, d)
    return d
