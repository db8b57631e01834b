"""Changes to a loaded study from the command line: ``--plates N``, ``--strategies a,b`` and
``--set KEY=VALUE`` (a dotted key of the study file, the value read as YAML). The changed study is
validated like the file, and checked against the base cell; errors name the key."""
from __future__ import annotations

from typing import Sequence

import yaml

from adaptive_cal.cell.schema import ConfigError, parse_cell
from adaptive_cal.formats.mapfiles import beside_glob
from adaptive_cal.study.config import Study, check_feasible, parse_study


def set_key(data: dict, item: str, create: bool = False) -> dict:
    """``data`` (a study as a mapping) with one ``KEY=VALUE`` applied: a new mapping, blocks
    copied on the way down, so ``data`` is left as it was. ``create``: a block the mapping lacks
    is made (a study file leaves out blocks it takes the defaults of)."""
    key, sep, value = item.partition("=")
    if not sep:
        raise ConfigError(f"--set {item!r}: expected KEY=VALUE")
    if not value.strip():  # a shell variable left unset: not a silent null
        raise ConfigError(f"--set {key}=: no value; give one (null clears the key)")
    *path, leaf = key.split(".")
    out = dict(data)
    node = out
    for part in path:
        if create and node.get(part) is None:
            node[part] = {}
        if not isinstance(node.get(part), dict):
            raise ConfigError(f"--set {key}: {part!r} is not a block of the study file")
        node[part] = dict(node[part])
        node = node[part]
    try:
        node[leaf] = yaml.safe_load(value)
    except yaml.YAMLError as e:
        problem = getattr(e, "problem", None) or type(e).__name__
        raise ConfigError(f"--set {key}={value}: the value is not YAML ({problem})") from None
    return out


def check_command_line(plates: int | None, strategies: str | None) -> None:
    """--plates and --strategies that name no study, refused before anything is read."""
    if plates is not None and plates < 1:
        raise ConfigError(f"--plates {plates}: a study runs at least 1 plate")
    if strategies is not None and not [s for s in strategies.split(",") if s.strip()]:
        raise ConfigError(f"--strategies {strategies!r}: name at least one strategy")


def apply_overrides(study: Study, base: dict, *, plates: int | None = None,
                    strategies: str | None = None, settings: Sequence[str] = (),
                    source: str = "overrides", study_path=None) -> Study:
    """The study with the command line's changes: ``plates`` (None: keep; at least 1),
    ``strategies`` (comma separated), ``settings`` (KEY=VALUE items, in order). Re-validated and
    checked against the base cell whenever anything changes (``example_plate`` below ``plates``
    included). A ``plate.surface_files`` given relative is taken, as in the file, relative to
    the study file (``study_path``), not to the folder the command runs in."""
    check_command_line(plates, strategies)
    if not (plates or strategies or settings):
        return study
    data = edited(study.model_dump(mode="json"), plates=plates, strategies=strategies)
    for item in settings:
        if item.partition("=")[0].strip() == "cell":  # the base cell was read with the file
            raise ConfigError(f"--set {item}: the base cell is the study file's 'cell:', read "
                              "with it; change it there (or copy the study file)")
        data = set_key(data, item)
        if item.partition("=")[0] == "plate.surface_files" and study_path is not None \
                and isinstance(data["plate"].get("surface_files"), str) \
                and data["plate"]["surface_files"]:
            data["plate"]["surface_files"] = beside_glob(data["plate"]["surface_files"], study_path)
    study = parse_study(data, source)
    check_feasible(study, parse_cell(base), source)
    return study


def edited(data: dict, *, plates: int | None = None, strategies: str | None = None,
           settings: Sequence[str] = ()) -> dict:
    """A study file's own mapping with the command line's changes, before it is validated: a
    --set mends a value the file has wrong (the changes are applied again, and checked, by
    ``apply_overrides``)."""
    if plates:
        data = {**data, "plates": plates}
    if strategies:
        data = {**data, "strategies": [s.strip() for s in strategies.split(",") if s.strip()]}
    for item in settings:
        if item.partition("=")[0].strip() != "cell":
            data = set_key(data, item, create=True)
    return data
