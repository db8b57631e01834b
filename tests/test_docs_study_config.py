"""docs/study-config.md is generated from the study schema: it must be current, and every key
the study files in configs/ use is in it (an outside audit, 2026-12-01: five keys of those files
were explained in their comments only)."""
from pathlib import Path

import yaml

from adaptive_cal.study.reference import study_reference

ROOT = Path(__file__).resolve().parents[1]


def test_the_study_reference_is_current():
    doc = (ROOT / "docs" / "study-config.md").read_text()
    assert doc == study_reference() + "\n", (
        "docs/study-config.md is stale: run `python -m adaptive_cal.study.reference > "
        "docs/study-config.md`")


def _keys(data, prefix=""):
    for k, v in data.items():
        yield f"{prefix}{k}"
        if isinstance(v, dict) and k != "cell":
            yield from _keys(v, f"{prefix}{k}.")


def test_every_key_of_the_example_study_files_is_documented():
    doc = (ROOT / "docs" / "study-config.md").read_text()
    for path in sorted((ROOT / "configs").glob("study-*.yaml")):
        for key in _keys(yaml.safe_load(path.read_text())):
            block, _, leaf = key.rpartition(".")
            section = doc.split(f"## `{block or '(top level)'}`", 1)
            assert len(section) == 2 and f"| `{leaf}` |" in section[1].split("\n## ", 1)[0], \
                f"{path.name}: {key} is not in docs/study-config.md"
