"""The docs site: it builds without a warning, and its generated tables are the code's."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from uav_depth.cli import docs

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted((ROOT / "docs").rglob("*.md"))


@pytest.mark.parametrize("page", [p for p in PAGES if docs.blocks(p.read_text())],
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_generated_tables_match_the_code(page):
    text = page.read_text()
    assert docs.refresh(text) == text, f"{page.name} is stale: run python -m uav_depth.cli.docs --write"


def test_every_generator_is_used_somewhere():
    used = {name for p in PAGES for name in docs.blocks(p.read_text())}
    assert used == set(docs.TABLES)


def test_refresh_rewrites_a_stale_table():
    stale = "x\n<!-- generated: params_table -->\n| old |\n<!-- end generated -->\ny\n"
    fresh = docs.refresh(stale)
    assert "| old |" not in fresh and "`sgbm.num_disparities`" in fresh and fresh.endswith("y\n")


def test_site_builds_strict(tmp_path):
    mkdocs = Path(sys.executable).with_name("mkdocs")
    out = subprocess.run([str(mkdocs), "build", "--strict", "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-4000:]
    assert "WARNING" not in out.stderr, out.stderr[-4000:]
    assert (tmp_path / "site" / "reference" / "parameters" / "index.html").exists()
