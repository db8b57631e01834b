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
    text = re.sub(r"Annotated\[(\w+), FieldInfo\(.*?\]\)\]", r"\1", text)  # bounds: in the text
    for wrapper in ("<class '", "'>"):
        text = text.replace(wrapper, "")
    return text.replace("|", "&#124;")


def _models(model: type[BaseModel], prefix: str, seen: dict, said: set | None = None):
    """(key path, model, the path where the same model was described first, or None), each
    path once (an optional block's class appears twice in its annotation)."""
    said = set() if said is None else said
    said.add(prefix)
    yield prefix, model, None
    for name, field in model.model_fields.items():
        for arg in (field.annotation, *typing.get_args(field.annotation)):
            inner = typing.get_args(arg) or (arg,)
            for cls in inner:
                if isinstance(cls, type) and issubclass(cls, BaseModel):
                    path = f"{prefix}.{name}" if prefix else name
                    if path in said:
                        continue
                    if cls in seen:
                        said.add(path)
                        yield path, cls, seen[cls]
                        continue
                    seen[cls] = path
                    yield from _models(cls, path, seen, said)


def _intro(model: type[BaseModel]) -> str:
    """The docstring's first paragraph on one line (its first line alone can stop mid-sentence)."""
    text = (model.__doc__ or "").strip().split("\n\n")[0]
    return " ".join(line.strip() for line in text.splitlines())


def _anchor(path: str) -> str:
    """GitHub's anchor of a heading "`a.b`": lower case, the dots and backquotes dropped."""
    return re.sub(r"[^a-z0-9_ -]", "", path.lower()).replace(" ", "-")


CELL_HEAD = ["# Cell file reference", "",
             "Generated from the schema by `python -m adaptive_cal.cell.doc`; a test keeps it "
             "current. Units: mm, s, deg, in the workplane frame. Unknown keys are refused, and "
             "every error names the key and the value. `configs/sim-cell.yaml` is a complete "
             "example.", ""]


def reference(model: type[BaseModel] = Cell, head: list[str] = CELL_HEAD) -> str:
    """The markdown reference of ``model``'s keys, block by block, under ``head``."""
    out = list(head)
    for prefix, model, same_as in _models(model, "", {}):
        if same_as is not None:
            out += [f"## `{prefix}`", "", f"The same keys as [`{same_as}`](#{_anchor(same_as)}): "
                    f"{_intro(model)}", ""]
            continue
        out += [f"## `{prefix or '(top level)'}`", "", _intro(model), "",
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
