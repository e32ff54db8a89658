"""User docs and examples never point to the developers' shared/ folder, and name the params file the
service reads (issue 15)."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
USER_FILES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "deploy").rglob("*.yaml"))]


def test_no_pointer_to_shared():
    for f in USER_FILES:
        for n, line in enumerate(f.read_text().splitlines(), 1):
            # "shared/loaded" describes the benchmark machine; a path into shared/ names a file in it
            assert not re.search(r"shared/(?!loaded)[A-Za-z]", line), f"{f.relative_to(ROOT)}:{n}: {line.strip()}"


def test_the_tuned_file_goes_where_the_service_reads_it():
    unit = (ROOT / "deploy" / "uav-depth.service").read_text() + (ROOT / "deploy" / "install.sh").read_text()
    assert "/var/lib/uav-depth/params.yaml" in unit
    for f in USER_FILES:
        assert "/etc/uav-depth/params.yaml" not in f.read_text(), f.relative_to(ROOT)


def test_what_the_examples_point_to_exists():
    """A comment naming a README section ('See README.md "SITL walk-through"') or a docs page names one that is
    there (issue 15: the SITL example pointed to a README section that did not exist)."""
    headings = {line.lstrip("#").strip() for line in (ROOT / "README.md").read_text().splitlines()
                if line.startswith("#")}
    pointers = 0
    for f in sorted((ROOT / "deploy" / "examples").glob("*.yaml")):
        for n, line in enumerate(f.read_text().splitlines(), 1):
            if not line.lstrip().startswith("#"):
                continue
            for title in re.findall(r'README(?:\.md)?\s+(?:section\s+)?"([^"]+)"', line):
                pointers += 1
                assert title in headings, f"{f.relative_to(ROOT)}:{n}: no README section {title!r}"
            for page in re.findall(r"\b(docs/[\w./-]+\.md)\b", line):
                pointers += 1
                assert (ROOT / page).is_file(), f"{f.relative_to(ROOT)}:{n}: {page} does not exist"
    assert pointers >= 1       # the SITL example says where its walk-through is
