"""Study inputs that failed late or as a bug: a zero noise told to the planner is refused naming
the study's own key; an unreachable Dask scheduler is the user's error (exit 2), not ours."""
import pytest
import yaml

from adaptive_cal.cell.schema import ConfigError, load_yaml, parse_cell
from adaptive_cal.cli import main
from adaptive_cal.study.config import check_feasible, parse_study

from helpers import ROOT

SMOKE = ROOT / "configs" / "study-smoke.yaml"
CELL = ROOT / "configs" / "sim-cell.yaml"


def _check(**plate):
    data = load_yaml(SMOKE)
    data["plate"] = {**data["plate"], **plate}
    check_feasible(parse_study(data, "s"), parse_cell(load_yaml(CELL)), "s")


@pytest.mark.parametrize("noise", [[0, 0], [0, 0.01], [0.0, 0.0]])
def test_a_noise_span_starting_at_zero_is_refused_naming_plate_noise_std_mm(noise):
    with pytest.raises(ConfigError, match=r"s: plate\.noise_std_mm=\[0\.0, .*\] starts at 0.*"
                                          r"noise_range_known: false"):
        _check(noise_std_mm=noise)


def test_zero_noise_is_fine_where_it_is_not_told_or_the_repeatability_adds_to_it():
    _check(noise_std_mm=[0, 0], noise_range_known=False)
    _check(noise_std_mm=[0, 0.01], repeatability_mm=0.002)
    _check(noise_std_mm=[0.001, 0.01])


def test_the_command_line_names_the_key_with_exit_2(tmp_path, capsys):
    data = load_yaml(SMOKE)
    data["cell"] = str(CELL)
    data["plate"] = {**data["plate"], "noise_std_mm": [0, 0]}
    study = tmp_path / "study.yaml"
    study.write_text(yaml.safe_dump(data))
    assert main(["study", str(study), "--json", str(tmp_path / "o.json"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "plate.noise_std_mm=[0.0, 0.0]" in err and "probe.noise_range_mm" in err
    assert "internal error" not in err


def test_an_unreachable_scheduler_is_a_user_error_naming_the_address(tmp_path, capsys,
                                                                     monkeypatch):
    from adaptive_cal.study import runner

    real = runner.connect
    monkeypatch.setattr(runner, "connect", lambda s, w: real(s, w, timeout_s=1.0))
    out = tmp_path / "o.json"
    assert main(["study", str(SMOKE), "--json", str(out), "--quiet", "--scheduler",
                 "tcp://127.0.0.1:1"]) == 2
    err = capsys.readouterr().err
    assert "--scheduler tcp://127.0.0.1:1: cannot reach the Dask scheduler" in err
    assert "internal error" not in err and "please report" not in err
    assert not out.exists()


def test_workers_without_dask_installed_say_which_extra_to_install(tmp_path, capsys,
                                                                   monkeypatch):
    """An outside audit (2026-12-01): --workers on the README's install (no Dask, an extra)
    was an 'internal error: ModuleNotFoundError'."""
    import builtins

    real = builtins.__import__

    def no_dask(name, *args, **kwargs):
        if name.split(".")[0] == "dask":
            raise ModuleNotFoundError("No module named 'dask'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_dask)
    out = tmp_path / "o.json"
    assert main(["study", str(SMOKE), "--json", str(out), "--quiet", "--workers", "2"]) == 2
    err = capsys.readouterr().err
    assert "pip install 'adaptive-cal[dask]'" in err and "--scheduler None" not in err
    assert "internal error" not in err and not out.exists()
