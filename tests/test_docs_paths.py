"""The docs name only files that exist: every repository path a page mentions is there."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
ROOMS = ("hdl", "master", "models", "cosim", "mrm", "protocol", "mrm_cosim", "configs", "tests",
         "benchmarks", "examples", "docs", ".ci")
# a path: a room, then folders and a file name with an extension (globs and <placeholders> are
# patterns, not files)
_ROOMS = "|".join(re.escape(r) for r in ROOMS)
PATH = re.compile(rf"(?<![\w./-])((?:{_ROOMS})/[\w./-]*\w\.(?:py|toml|md|png|csv|json))")


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_path_a_page_names_exists(page):
    text = page.read_text()
    missing = sorted({m for m in PATH.findall(text)
                      if not (ROOT / m).exists() and not (page.parent / m).exists()})
    assert not missing, f"{page.relative_to(ROOT)} names files that do not exist: {missing}"
