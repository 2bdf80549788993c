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


LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _anchors(path: Path) -> set[str]:
    """GitHub's anchors of a page's headings (lower case, punctuation dropped, spaces → -)."""
    out = set()
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            out.add(re.sub(r"[^\w\- ]", "", line.lstrip("#").strip().lower()).replace(" ", "-"))
    return out


@pytest.mark.parametrize("page", ["README.md"] + sorted(f"docs/{p.name}" for p in (REPO / "docs").glob("*.md")))
def test_every_link_of_a_page_lands(page):
    """Relative links of the README and docs/ reach a file that exists, and a heading there
    when they name one (the README's sections moved into docs/ with their links)."""
    src = REPO / page
    broken = []
    for target in LINK.findall(src.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+:", target):
            continue
        file, _, anchor = target.partition("#")
        dest = (src.parent / file).resolve() if file else src
        if not dest.exists():
            broken.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(target)
    assert not broken, f"{page}: links that land nowhere: {broken}"
