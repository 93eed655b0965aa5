"""Rules the test suite keeps about itself (issue 17): our own modules are imported, never skipped."""

import re
from pathlib import Path

TESTS = Path(__file__).parent


def test_no_importorskip_of_bodystudio_modules():
    """``pytest.importorskip("bodystudio...")`` turns an import error in our code into a silent skip; only
    outside tools may be skipped when missing."""
    pattern = re.compile(r"importorskip\(\s*[\"']bodystudio")
    offenders = [f"{p.relative_to(TESTS)}:{i}" for p in TESTS.rglob("*.py") if p != Path(__file__)
                 for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not offenders, f"import our modules directly instead: {offenders}"
