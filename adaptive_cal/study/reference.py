"""The study-file reference (docs/study-config.md), generated from the schema so it cannot drift.

    python -m adaptive_cal.study.reference > docs/study-config.md
"""
from __future__ import annotations

from adaptive_cal.cell.doc import reference
from adaptive_cal.study.config import Study

HEAD = ["# Study file reference", "",
        "Generated from the schema by `python -m adaptive_cal.study.reference`; a test keeps it "
        "current. A study file (`adaptive-cal study STUDY.yaml`, docs/study.md) names a base "
        "cell and how its plates are drawn. Units: mm, deg. Unknown keys are refused, and every "
        "error names the key and the value; `--set KEY=VALUE` overrides any key below. "
        "`configs/study-tilts.yaml` is a complete example.", ""]


def study_reference() -> str:
    return reference(Study, HEAD)


if __name__ == "__main__":  # pragma: no cover
    print(study_reference())
