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
