"""Safety at load: no NaN or infinity, physical ranges, duplicate keys, alias bombs, deep nesting,
short messages, a printable cell name -- each refused with the key or the line named."""
import time

import pytest
import yaml

from adaptive_cal.cell.files import ECHO_CHARS, ConfigError, echo, parse_yaml
from adaptive_cal.cell.schema import load_cell, load_yaml, parse_cell

from helpers import ROOT, SIM_CELL


def _cell(tmp_path, text):
    f = tmp_path / "cell.yaml"
    f.write_text(text)
    return load_cell(f)


def _patched(**sections):
    data = load_yaml(SIM_CELL)
    for key, value in sections.items():
        data[key] = {**data.get(key, {}), **value}
    return data


@pytest.mark.parametrize("section,key,value", [
    ("robot", "safe_height_mm", float("nan")), ("robot", "safe_height_mm", float("inf")),
    ("robot", "base_xy_mm", [float("nan"), 0.0]), ("probe", "zero_mm", float("-inf")),
    ("probe", "resolution_mm", float("nan")), ("probe", "noise_std_mm", float("inf")),
    ("plan", "drift_std_mm", float("nan")),
])
def test_nan_and_infinity_are_refused_naming_the_key(section, key, value):
    with pytest.raises(ConfigError, match=f"{section}.{key}.*finite"):
        parse_cell(_patched(**{section: {key: value}}))


def test_nan_in_text_and_in_nested_blocks_is_refused(tmp_path):
    base = SIM_CELL.read_text()
    for old, new, key in [("safe_height_mm: 15", "safe_height_mm: .nan", "robot.safe_height_mm"),
                          ("zero_mm: 5.0", "zero_mm: 1e999", "probe.zero_mm"),
                          ("a: 0.0140", "a: .inf", "simulation.effects.tilt.a"),
                          ("safe_height_mm: 15", "safe_height_mm: 'nan'", "robot.safe_height_mm")]:
        assert old in base
        with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
            _cell(tmp_path, base.replace(old, new))


@pytest.mark.parametrize("patch,match", [
    ({"robot": {"safe_height_mm": -10}}, "robot.safe_height_mm"),
    ({"robot": {"safe_height_mm": 0}}, "robot.safe_height_mm"),
    ({"robot": {"safe_height_mm": 1e6}}, "robot.safe_height_mm"),
    ({"robot": {"safe_height_mm": 70}}, "workspace.z_mm"),  # above the workspace box
    ({"probe": {"zero_mm": -100}}, "probe.zero_mm"),
    ({"probe": {"zero_mm": 12}}, "zero_mm=12.*stroke"),
    ({"probe": {"resolution_mm": 0}}, "probe.resolution_mm"),
    ({"probe": {"resolution_mm": 10}}, "resolution_mm=10.*below the stroke"),
    ({"probe": {"samples": 10**6}}, "probe.samples"),
    ({"model": {"knots_x": 10**5}}, "model.knots_x"),
    ({"plan": {"candidates": 10**9}}, "plan.candidates"),
    ({"workplane": {"x_mm": [-1e9, 1e9]}}, "workplane.x_mm"),
    # a floor above the budget: every run ended INCOMPLETE with no word before (an audit)
    ({"plan": {"stop": {"max_touches": 40, "min_touches": 50}}},
     r"plan.stop.min_touches: min_touches=50 is above max_touches=40"),
    # knots short of the workplane: refused when the model was built, naming neither (an audit)
    ({"model": {"knots_x": [-100, 0, 100]}}, r"model.knots_x=\[-100.0, 0.0, 100.0\] must begin "
                                             r"and end on the edges of workplane.x_mm=\[-225.0, "
                                             r"225.0\]"),
    # knots beyond it: the stop's RMS std counted area no touch reaches, 16.8 um for 5.3 (an audit)
    ({"model": {"knots_y": [-285, 0, 285]}}, r"model.knots_y=\[-285.0, 0.0, 285.0\] must begin "
                                             r"and end on the edges of workplane.y_mm"),
])
def test_values_outside_a_physical_range_are_refused_naming_the_key(patch, match):
    with pytest.raises(ConfigError, match=match):
        parse_cell(_patched(**patch))


def test_a_real_robot_travels_above_the_free_probe_tip():
    data = yaml.safe_load((ROOT / "configs" / "cell-manual.yaml").read_text())
    data["robot"]["safe_height_mm"] = 4.0  # the tip hangs 5 mm (zero_mm) below: it would drag
    with pytest.raises(ConfigError, match="safe_height_mm=4.0 must be above probe.zero_mm=5.0"):
        parse_cell(data)
    data["robot"]["safe_height_mm"] = 6.0
    assert parse_cell(data).robot.safe_height_mm == 6.0


def test_a_duplicate_key_is_refused_naming_the_key_and_both_lines(tmp_path):
    text = SIM_CELL.read_text().replace("  safe_height_mm: 15\n",
                                        "  safe_height_mm: 15\n  safe_height_mm: -10\n")
    line = text.splitlines().index("  safe_height_mm: -10") + 1
    with pytest.raises(ConfigError, match=f":{line}: key 'safe_height_mm' given twice "
                                          f"\\(first on line {line - 1}\\)"):
        _cell(tmp_path, text)
    # a merge key (<<) is not a duplicate, and the shipped alias config still loads
    assert load_cell(ROOT / "configs" / "cell-modbus-emulated.yaml").robot.adapter == "modbus"


def test_an_alias_bomb_is_refused_at_once_with_a_short_message(tmp_path):
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 10)]
    text = "\n".join(lines) + "\nname: *a9\n"  # 9**10 = 3.5e9 strings once expanded
    assert len(text) < 1100
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match="expands to more than") as e:
        _cell(tmp_path, text)
    assert time.monotonic() - t0 < 1.0 and len(str(e.value)) < 300


def test_deep_nesting_and_recursive_aliases_are_refused_quickly(tmp_path):
    for text in ("[" * 10000 + "]" * 10000, "a: " + "{b: " * 5000 + "1" + "}" * 5000,
                 "".join(" " * i + "k:\n" for i in range(1000)), "- " * 400_000 + "1\n",
                 "a: &a [*a]\n"):  # "- " * 400000 crashed libyaml's composer (C stack)
        t0 = time.monotonic()
        with pytest.raises(ConfigError, match="nested|recursive|characters"):
            _cell(tmp_path, text)
        assert time.monotonic() - t0 < 2.0


def test_echoed_values_are_short():
    huge = {"k": ["x" * 10**6] * 1000}
    assert len(echo(huge)) <= ECHO_CHARS
    with pytest.raises(ConfigError) as e:
        parse_cell(_patched(robot={"colour": "y" * 10**5}))
    assert "robot.colour" in str(e.value) and len(str(e.value)) < 400


@pytest.mark.parametrize("name", ["two\nlines", "tab\there", "bell\x07", "", "x" * 201])
def test_a_cell_name_is_one_line_of_printable_text(name):
    with pytest.raises(ConfigError, match="name"):
        parse_cell({**load_yaml(SIM_CELL), "name": name})
    assert parse_cell({**load_yaml(SIM_CELL), "name": "Zelle 3 (Halle B) – plate #2"})


def test_every_shipped_cell_file_still_loads():
    for f in sorted((ROOT / "configs").glob("*.yaml")):
        if "study" not in f.name:
            assert load_cell(f).name


def test_parse_yaml_keeps_ordinary_documents():
    assert parse_yaml("") is None
    assert parse_yaml("a: &x {b: 1}\nc: *x\nd: {<<: *x, e: 2}\n") == {
        "a": {"b": 1}, "c": {"b": 1}, "d": {"b": 1, "e": 2}}


@pytest.mark.parametrize("box,key", [
    ({"x_mm": [0, 230], "y_mm": [-190, 190], "z_mm": [-20, 60]}, "workspace.x_mm"),
    ({"x_mm": [-230, 230], "y_mm": [-150, 190], "z_mm": [-20, 60]}, "workspace.y_mm"),
])
def test_a_workspace_that_does_not_hold_the_touchable_plate_is_refused(box, key):
    """The planner would choose touches inside the plate that the probe cycle then refuses."""
    data = load_yaml(SIM_CELL)
    data["workspace"] = box
    with pytest.raises(ConfigError, match=rf"\n  {key}: {key}=.*does not hold the touchable plate"):
        parse_cell(data)


@pytest.mark.parametrize("config", ["cell-manual.yaml", "cell-hses-emulated.yaml",
                                    "cell-modbus-emulated.yaml"])
def test_a_cell_that_moves_a_real_probe_must_give_its_workspace(config):
    data = yaml.safe_load((ROOT / "configs" / config).read_text())
    parse_cell(data)  # as shipped: fine
    del data["workspace"]
    with pytest.raises(ConfigError, match=r"\n  robot.adapter: .*give a workspace block"):
        parse_cell(data)


def test_a_yes_no_is_no_number_but_yaml_exponents_without_a_dot_are():
    """YAML reads `true`, `yes`, `on` as a bool, and pydantic would take it as 1: refused naming
    the key. PyYAML reads `4e-3` (no dot) as text; a cell file that writes it means 0.004."""
    from helpers import sim_cell

    assert yaml.safe_load("v: 4e-3")["v"] == "4e-3"  # the YAML quirk itself
    for value in (True, False):
        with pytest.raises(ConfigError, match=r"plan\.stop\.max_touches: a yes/no, not a "
                                              r"number \(YAML reads yes, no, on, off, true and "
                                              r"false as one: here (True|False)\)"):
            sim_cell(plan={"stop": {"max_touches": value}})
    stop = yaml.safe_load("mean_std_mm: 4e-3\nmax_touches: 40")
    assert sim_cell(plan={"stop": stop}).plan.stop.mean_std_mm == 0.004
