"""docs/config.md is generated from the schema: it must be current."""
from pathlib import Path

from adaptive_cal.cell.doc import reference


def test_config_reference_is_current():
    doc = Path(__file__).resolve().parents[1] / "docs" / "config.md"
    assert doc.read_text().strip() == reference().strip(), \
        "docs/config.md is stale: run `python -m adaptive_cal.cell.doc > docs/config.md`"
