"""Study files: impossible distributions are refused with a message naming the key."""
import copy

import pytest

from adaptive_cal.cli import main
from adaptive_cal.cell.schema import ConfigError, load_yaml, parse_cell
from adaptive_cal.study.config import check_feasible, load_study, parse_study
from adaptive_cal.study.plates import plate_cell, sample_plate

from conftest import ROOT

SMOKE = ROOT / "configs" / "study-smoke.yaml"


def _study(**changes):
    data = load_yaml(SMOKE)
    for key, value in changes.items():
        block, _, leaf = key.partition(".")
        if leaf:
            data.setdefault(block, {})[leaf] = value
        else:
            data[block] = value
    return data


def _check(data):
    study = parse_study(data, "s")
    cell = parse_cell(load_yaml(ROOT / "configs" / "sim-cell.yaml"))
    check_feasible(study, cell, "s")


def test_shipped_studies_load():
    for name in ("study-smoke.yaml", "study-tilts.yaml"):
        study, base = load_study(ROOT / "configs" / name)
        assert study.plates >= 1 and "workplane" in base


@pytest.mark.parametrize("key, value, words", [
    ("plate.noise_std_mm", [-0.001, 0.01], "plate.noise_std_mm"),
    ("plate.form_pv_mm", [0.3, 0.1], "plate.form_pv_mm"),
    ("plate.tilt_dg", 1.0, "plate.tilt_dg"),
    ("bound.mean_std_mm", -1.0, "bound.mean_std_mm"),
    ("strategies", ["adaptive", "bogus"], "strategies"),
])
def test_schema_refuses_naming_the_key(key, value, words):
    with pytest.raises(ConfigError, match=words.replace(".", r"\.")):
        parse_study(_study(**{key: value}), "s")


def test_tilt_beyond_the_stroke_is_refused():
    with pytest.raises(ConfigError, match=r"plate\.tilt_deg=8.*stroke"):
        _check(_study(**{"plate.tilt_deg": 8.0}))


def test_bound_below_the_noise_floor_is_refused():
    with pytest.raises(ConfigError, match=r"bound\.mean_std_mm=0\.0001 is below the noise floor"):
        _check(_study(**{"bound.mean_std_mm": 0.0001}))


def test_feasible_study_passes():
    _check(_study())


def test_cli_refuses_bad_study(tmp_path, capsys):
    bad = copy.deepcopy(load_yaml(SMOKE))
    bad["plate"]["noise_std_mm"] = [-0.01, 0.02]
    bad["cell"] = str(ROOT / "configs" / "sim-cell.yaml")
    path = tmp_path / "bad.yaml"
    import yaml

    path.write_text(yaml.safe_dump(bad))
    assert main(["study", str(path), "--json", str(tmp_path / "o.json")]) == 2
    assert "plate.noise_std_mm" in capsys.readouterr().err


def test_study_tells_the_planner_the_noise_span_unless_switched_off():
    study, base = load_study(ROOT / "configs" / "study-tilts.yaml")
    plate = sample_plate(study, 0)
    assert plate_cell(study, base, plate).probe.noise_range_mm == (0.005, 0.02)
    off = study.model_copy(update={"plate": study.plate.model_copy(
        update={"noise_range_known": False})})
    assert plate_cell(off, base, plate).probe.noise_range_mm is None


def test_overrides_set_keys_strategies_and_plates_and_name_bad_keys():
    from adaptive_cal.study.overrides import apply_overrides, set_key

    study, base = load_study(SMOKE)
    data = study.model_dump(mode="json")
    changed = set_key(data, "bound.true_rms_mm=0.01")
    assert changed["bound"]["true_rms_mm"] == 0.01 and data["bound"]["true_rms_mm"] is None
    assert set_key(data, "plate.form_shapes=[bow_x, twist]")["plate"]["form_shapes"] == \
        ["bow_x", "twist"]
    out = apply_overrides(study, base, plates=2, strategies="paper, grid",
                          settings=["bound.true_rms_mm=0.02", "lower_bound.plates=0"])
    assert (out.plates, out.strategies, out.bound.true_rms_mm, out.lower_bound.plates) == \
        (2, ["paper", "grid"], 0.02, 0)
    assert apply_overrides(study, base) is study
    assert apply_overrides(study, base, plates=5).plates == 5
    for bad in (0, -3):  # refused naming the flag, before any plate is drawn
        with pytest.raises(ConfigError, match=f"--plates {bad}: a study runs at least 1 plate"):
            apply_overrides(study, base, plates=bad)
    with pytest.raises(ConfigError, match="example_plate"):  # validated, not copied over
        apply_overrides(study.model_copy(update={"example_plate": 3}), base, plates=2)
    for item, words in (("bound.true_rms_mm", "expected KEY=VALUE"),
                        ("plates.x=1", "'plates' is not a block"),
                        ("bound.mean_std_mm=-1", "bound.mean_std_mm"),
                        ("bound.mean_std_mm=1e-9", "noise floor")):
        with pytest.raises(ConfigError, match=words):
            apply_overrides(study, base, settings=[item])
