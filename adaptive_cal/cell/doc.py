"""The cell-file reference (docs/config.md), generated from the schema so it cannot drift.

    python -m adaptive_cal.cell.doc > docs/config.md
"""
from __future__ import annotations

import re
import typing

from pydantic import BaseModel

from adaptive_cal.cell.schema import Cell


def _type(annotation) -> str:
    text = str(annotation).replace("typing.", "").replace("NoneType", "None")
    text = re.sub(r"adaptive_cal(\.\w+)*\.(?=[A-Z])", "", text)  # a class's module path
    for wrapper in ("<class '", "'>"):
        text = text.replace(wrapper, "")
    return text.replace("|", "&#124;")


def _models(model: type[BaseModel], prefix: str, seen: set):
    yield prefix, model
    for name, field in model.model_fields.items():
        for arg in (field.annotation, *typing.get_args(field.annotation)):
            inner = typing.get_args(arg) or (arg,)
            for cls in inner:
                if isinstance(cls, type) and issubclass(cls, BaseModel) and cls not in seen:
                    seen.add(cls)
                    yield from _models(cls, f"{prefix}.{name}" if prefix else name, seen)


def reference() -> str:
    out = ["# Cell file reference", "",
           "Generated from the schema by `python -m adaptive_cal.cell.doc`; a test keeps it "
           "current. Units: mm, s, deg, in the workplane frame. Unknown keys are refused, and "
           "every error names the key and the value. `configs/sim-cell.yaml` is a complete "
           "example.", ""]
    for prefix, model in _models(Cell, "", set()):
        out += [f"## `{prefix or '(top level)'}`", "", (model.__doc__ or "").strip().splitlines()[0], "",
                "| key | type | default | meaning |", "|---|---|---|---|"]
        for name, field in model.model_fields.items():
            default = "required" if field.is_required() else field.get_default()
            default = ("see below" if isinstance(default, BaseModel) else
                       default if default == "required" else repr(default))
            out.append(f"| `{name}` | {_type(field.annotation)} | {default if default in ('required', 'see below') else '`' + default + '`'} | "
                       f"{(field.description or '').replace('|', '/')} |")
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":  # pragma: no cover
    print(reference())
