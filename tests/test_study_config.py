"""Study files: impossible distributions are refused with a message naming the key."""
import copy
import json

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
    ("seed", -1, "seed"),  # refused here, not by numpy once the checkpoint exists
    ("plate.repeatability_mm", 1e300, "plate.repeatability_mm"),  # an OverflowError later
    ("bound.max_touches", 100_000_000, "bound.max_touches"),  # named as the cell's key later
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
                        ("bound.mean_std_mm=1e-9", "noise floor"),
                        ("bound.max_touches=[1,", r"--set bound.max_touches=\[1,: the value is "
                         "not YAML"),
                        # a shell variable left unset ($MAPS): it had become null, and the
                        # study quietly ran on drawn plates (an outside audit, 2026-11-30)
                        ("plate.surface_files=", r"--set plate.surface_files=: no value"),
                        ("plate.surface_files= ", "null clears the key")):
        with pytest.raises(ConfigError, match=words):
            apply_overrides(study, base, settings=[item])
    for empty in ("", " , "):  # an empty list is refused, not taken for "the file's"
        with pytest.raises(ConfigError, match="name at least one strategy"):
            apply_overrides(study, base, strategies=empty)


def test_a_budget_below_the_papers_first_round_is_refused_with_paper():
    data = _study(**{"bound.max_touches": 40, "strategies": ["adaptive", "paper"]})
    with pytest.raises(ConfigError, match=r"bound\.max_touches=40 is less than the paper's first "
                                          r"round, 45 touches"):
        _check(data)
    _check(_study(**{"bound.max_touches": 40, "strategies": ["adaptive", "grid"]}))


def test_a_damaged_checkpoint_is_named_and_records_that_are_not_plates_run_again(tmp_path):
    """A damaged line in the middle is skipped and its number told; the records after it are
    kept (an outside audit: one blank line threw away the 10 records after it, silently)."""
    from adaptive_cal.study.checkpoint import read_checkpoint

    f = tmp_path / "plates.jsonl"
    for first in ("garbage", "[1, 2]", '{"other": 1}'):
        f.write_text(first + "\n")
        with pytest.raises(ValueError, match=r"plates\.jsonl: not a study's checkpoint"):
            read_checkpoint(f, "k")
    f.write_text('{"study_key": "k"}\n{"plate": 0, "strategy": "grid"}\n[1, 2]\n\n'
                 '{"plate": 1, "strategy": "grid"}\n{"plate": 0, "strategy": "grid"}\n{"pla')
    skipped = []
    assert read_checkpoint(f, "k", skipped) == [{"plate": 0, "strategy": "grid"},
                                                {"plate": 1, "strategy": "grid"}]
    assert skipped == [3]  # the blank line is no damage, the cut last line an interruption's
    with pytest.raises(ValueError, match="another study .*another --out, or another --json"):
        read_checkpoint(f, "j")


def test_a_plate_with_no_design_within_the_budget_leaves_the_bounds_means_finite(tmp_path):
    """One plate's relaxed bound is inf (no design meets the bound within the budget): it is
    counted, left out of every mean and ratio alike, and --json holds no Infinity."""
    import json
    import math

    from adaptive_cal.run.folder import write_json
    from adaptive_cal.study.summary import summarise, table

    study = parse_study(_study(**{"strategies": ["adaptive"], "plates": 2}), "s")
    lines = (ROOT / "docs" / "study" / "plates.jsonl").read_text().splitlines()[1:]
    one = next(r for r in map(json.loads, lines) if r["strategy"] == "adaptive")
    recs = [{**one, "plate": plate, "relaxed_touches": relaxed, "best_integer_touches": None}
            for plate, relaxed in ((0, 20.0), (1, math.inf))]
    s = summarise(study, recs)
    lb = s["lower_bound"]
    assert lb["plates"] == 1 and lb["plates_beyond_budget"] == 1
    assert lb["relaxed_touches"] == 20.0 and math.isfinite(lb["adaptive_over_relaxed"])
    assert "on 1 plate no design meets the bound within the touch budget" in table(s)
    write_json(tmp_path / "s.json", {**s, "x": math.inf})
    assert "Infinity" not in (tmp_path / "s.json").read_text()
    assert json.loads((tmp_path / "s.json").read_text())["x"] is None


def test_outputs_that_would_overwrite_what_they_should_not_are_refused(tmp_path, capsys):
    import json

    out = tmp_path / "o"
    # --json onto the table the study writes into --out (it was replaced by the table)
    assert main(["study", str(SMOKE), "--out", str(out), "--json", str(out / "table.md")]) == 2
    assert "the study writes its table.md there" in capsys.readouterr().err
    # --json onto a JSON file that is not an earlier study's summary
    precious = tmp_path / "calibration.json"
    precious.write_text(json.dumps({"calibration": "do not lose"}))
    assert main(["study", str(SMOKE), "--json", str(precious)]) == 2
    assert "is not an earlier study's --json" in capsys.readouterr().err
    assert json.loads(precious.read_text()) == {"calibration": "do not lose"}


def test_settings_that_change_nothing_are_said():
    """Drawn-plate keys beside plate.surface_files are warned about; a study without the
    adaptive strategy says why it has no lower bound (an outside audit: both were silent)."""
    from adaptive_cal.cli.study import ignored
    from adaptive_cal.study.summary import summarise

    study, _ = load_study(SMOKE)
    assert ignored(study) == []
    maps = study.model_copy(update={"plate": study.plate.model_copy(
        update={"surface_files": "maps/*.csv", "tilt_deg": 0.9})})
    (line,) = ignored(maps)
    assert line.startswith("plate.tilt_deg, plate.form_pv_mm not used: plate.surface_files") \
        or line.startswith("plate.tilt_deg not used: plate.surface_files"), line
    grid_only = study.model_copy(update={"strategies": ["grid"]})
    assert "does not run" in summarise(grid_only, [])["lower_bound"]["why_none"]


def test_the_paper_strategys_levelling_points_keep_out_of_keep_outs():
    """An outside audit (2026-12-02): the paper strategy's 5 levelling points were never
    filtered; with a keep-out over the centre and one over a corner it touched both."""
    import numpy as np

    from adaptive_cal.study.designs import paper_points
    from adaptive_cal.study.config import Paper
    from tests.helpers import sim_cell

    cell = sim_cell(workplane={"keep_outs": [{"x_mm": [-30, 30], "y_mm": [-30, 30]},
                                             {"x_mm": [150, 225], "y_mm": [120, 185]}]})
    level, path = paper_points(cell, Paper())
    assert len(level) == 3
    assert all(cell.workplane.allows(x, y) for x, y in np.vstack([level, path]))


def test_a_set_mends_a_value_the_file_has_wrong(tmp_path, capsys):
    """`--set` was applied after the file was validated: a bad value in the file could not be
    mended from the command line, the file's error came first (an outside audit)."""
    from adaptive_cal.cli import main

    text = (ROOT / "configs" / "study-smoke.yaml").read_text().replace("max_touches: 60",
                                                                      "max_touches: -5")
    study = tmp_path / "study.yaml"
    study.write_text(text.replace("cell: sim-cell.yaml",
                                  f"cell: {ROOT / 'configs' / 'sim-cell.yaml'}"))
    argv = ["study", str(study), "--plates", "1", "--strategies", "grid", "--quiet", "--json",
            str(tmp_path / "s.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "bound.max_touches" in err
    assert main(argv + ["--set", "lower_bound.plates=0"]) == 2  # another key: the file's error
    assert "bound.max_touches" in capsys.readouterr().err
    assert main(argv + ["--set", "bound.max_touches=40"]) == 0
    assert json.loads((tmp_path / "s.json").read_text())["bound"]["max_touches"] == 40
    # the file mended, the change itself wrong: that is said, as the command line's
    assert main(argv + ["--set", "bound.max_touches=40", "--set", "bound.mean_std_mm=-1"]) == 2
    err = capsys.readouterr().err
    assert "bound.mean_std_mm" in err and "(with the command line's changes)" in err
    # a second bad value in the file, the first mended: the file's, not the change's (an outside
    # review: it was said to come with the command line's changes)
    study.write_text(study.read_text().replace("mean_std_mm: 0.01", "mean_std_mm: -0.01"))
    assert main(argv + ["--set", "bound.max_touches=40"]) == 2
    err = capsys.readouterr().err
    assert "bound.mean_std_mm" in err and "(in the file, the command line's changes applied)" in err
    assert main(argv[:4] + ["--strategies", ",", "--json", str(tmp_path / "s.json")]) == 2
    assert "--strategies ',': name at least one strategy" in capsys.readouterr().err


@pytest.mark.parametrize("item, said", [
    ("plate.noise_std_mm=[5, 20]", "plate.noise_std_mm up to 20 mm is 222% of the probe's usable "
     "stroke 9 mm: um given as mm? (20 um is 0.02 mm)"),
    ("bound.mean_std_mm=10", "bound.mean_std_mm=10 mm is above the RMS std of the cell's prior "
     "before any touch"),
    ("bound.true_rms_mm=5", "bound.true_rms_mm=5 mm is above the RMS std"),
])
def test_a_study_in_um_is_named_as_such(item, said):
    """An outside audit: noise typed in um was blamed on the bound ("below the noise floor"), a
    bound of 10 mm was accepted and every run stopped on the prior."""
    from adaptive_cal.study.overrides import apply_overrides

    study, base = load_study(SMOKE)
    with pytest.raises(ConfigError) as e:
        apply_overrides(study, base, settings=[item])
    assert said in str(e.value)
    assert "noise floor" not in str(e.value)
