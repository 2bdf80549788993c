"""The docs name real files: every repository path a page of ``docs/`` writes in backticks
(``cell/…``, ``drivers/…``, ``bench/…``, ``tests/…``, ``deploy/…``, ``recipes/…``) exists, so a
newcomer who follows one lands somewhere."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PATH = re.compile(r"`((?:cell|drivers|bench|tests|deploy|recipes|docs)/[\w./-]*)`")


@pytest.mark.parametrize("page", sorted(p.name for p in (REPO / "docs").glob("*.md")))
def test_every_path_a_docs_page_names_exists(page):
    text = (REPO / "docs" / page).read_text(encoding="utf-8")
    named = sorted(set(PATH.findall(text)))
    missing = [p for p in named if not (REPO / p.rstrip("/")).exists()]
    assert not missing, f"docs/{page} names paths that do not exist: {missing}"


def test_the_glossary_says_where_each_seed_lives():
    text = (REPO / "docs" / "glossary.md").read_text(encoding="utf-8")
    for seed in ("000", "001", "002", "003", "004"):
        assert f"| **{seed}** |" in text, seed
    assert len(PATH.findall(text)) >= 10
