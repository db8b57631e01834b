"""Running studies: Dask equals in-process, interrupted studies resume, vmap equals the loop."""
import json
import time

import numpy as np
import pytest

from adaptive_cal.study.config import load_study, parse_study
from adaptive_cal.study.designs import evaluate_loop, evaluate_vmap
from adaptive_cal.study.plates import plate_cell, sample_plate
from adaptive_cal import use_float64
from adaptive_cal.study.runner import SchedulerError, connect, run_study
from adaptive_cal.study.summary import summarise
from adaptive_cal.study.strategies import Context

from conftest import ROOT

SMOKE = ROOT / "configs" / "study-smoke.yaml"


def _small(**changes):
    study, base = load_study(SMOKE)
    data = study.model_dump(mode="json")
    data.update(plates=2, strategies=["adaptive", "paper", "random"], estimator="fixed",
                lower_bound={"plates": 0})
    data["bound"].update(mean_std_mm=0.015, max_touches=45)
    data.update(changes)
    return parse_study(data), base


def _strip(records):
    return sorted(((r["plate"], r["strategy"]), {k: v for k, v in r.items()}) for r in records)


@pytest.mark.slow
def test_dask_local_cluster_equals_in_process(tmp_path):
    study, base = _small()
    calls = []
    local = run_study(study, base, tmp_path / "a.jsonl", progress=lambda d, t: calls.append((d, t)))
    # runs (strategy x plate): 0 at the start, then each adaptive plate, then each fixed design's
    # batch of 2 plates
    assert calls == [(0, 6), (1, 6), (2, 6), (4, 6), (6, 6)]
    client = connect(None, 2)
    try:
        assert len(client.scheduler_info()["workers"]) == 2
        remote = run_study(study, base, tmp_path / "b.jsonl", client=client,
                           worker_setup=use_float64)
    finally:
        client.close()
    a, b = _strip(local), _strip(remote)
    assert [k for k, _ in a] == [k for k, _ in b] and len(a) == 6
    for (_, ra), (_, rb) in zip(a, b):
        assert ra.keys() == rb.keys()
        for key in ra:
            if isinstance(ra[key], float):
                assert ra[key] == pytest.approx(rb[key], rel=1e-9, abs=1e-12), key
            else:
                assert ra[key] == rb[key] or key in ("trajectory", "xy"), key
        np.testing.assert_allclose(np.asarray(ra["trajectory"], float),
                                   np.asarray(rb["trajectory"], float), rtol=1e-9, atol=1e-12)
    assert summarise(study, local)["strategies"].keys() == {"adaptive", "paper", "random"}


def test_interrupted_study_keeps_finished_plates(tmp_path):
    study, base = _small(strategies=["adaptive"])
    path = tmp_path / "plates.jsonl"
    first = run_study(study, base, path, limit=1)  # "interrupted" after one plate
    assert len(first) == 1
    from adaptive_cal.study.plates import sample_plate

    drawn = sample_plate(study, first[0]["plate"])  # the record names its plate's truth
    assert first[0]["simulation"]["effects"] == drawn.effects
    assert first[0]["simulation"]["seed"] == drawn.seed
    with open(path, "a") as f:
        f.write('{"cut": ')  # a line cut by the interruption
    calls = []
    again = run_study(study, base, path, progress=lambda d, t: calls.append((d, t)))
    assert calls == [(0, 1), (1, 1)]  # only the missing plate ran
    assert len(again) == 2 and again[0] == first[0]
    lines = path.read_text().splitlines()
    assert json.loads(lines[0])["study_key"] and len(lines) == 3
    other, _ = _small(seed=99, strategies=["adaptive"])
    with pytest.raises(ValueError, match="another study"):
        run_study(other, base, path)


def test_plates_grows_or_cuts_a_study_keeping_its_records(tmp_path):
    """--plates was part of the study's key: 40 plates and then 41 were two studies, and the
    41st plate cost the 40 again (an outside audit). Plate i is drawn from the seed and i."""
    study, base = _small(strategies=["adaptive"], plates=1)
    path = tmp_path / "plates.jsonl"
    one = run_study(study, base, path)
    grown, _ = _small(strategies=["adaptive"], plates=2)
    calls = []
    two = run_study(grown, base, path, progress=lambda d, t: calls.append((d, t)))
    assert calls == [(0, 1), (1, 1)] and [r["plate"] for r in two] == [0, 1]  # only plate 1 ran
    assert two[0] == one[0]
    assert run_study(study, base, path) == one  # cut back: plate 0 alone, nothing run


def test_a_ctrl_c_mid_plate_keeps_the_strategies_that_finished(tmp_path, monkeypatch):
    """In-process, a plate's records reached the checkpoint when all its strategies were done:
    a Ctrl-C during the last lost the others (an outside audit)."""
    import adaptive_cal.study.strategies as strategies

    def planner(ctx, learn, **kw):
        if not learn:
            raise KeyboardInterrupt
        return {"plate": 0, "strategy": "adaptive", "touches": 12}

    monkeypatch.setattr(strategies, "run_planner", planner)
    study, base = _small(strategies=["adaptive", "greedy_fixed"], estimator="learned", plates=1)
    path = tmp_path / "plates.jsonl"
    with pytest.raises(KeyboardInterrupt):
        run_study(study, base, path)
    kept = [json.loads(line) for line in path.read_text().splitlines()[1:]]
    assert [(r["plate"], r["strategy"], r["touches"]) for r in kept] == [(0, "adaptive", 12)]


@pytest.mark.slow
def test_a_plates_strategies_split_into_tasks_give_the_same_records():
    """On Dask a plate's strategies go as tasks of their own (the paper with the planner, which
    runs on to its accuracy): a Ctrl-C loses only the tasks in flight. Split or whole, the
    records are the same."""
    from adaptive_cal.study.runner import _parts
    from adaptive_cal.study.tasks import plate_task

    assert _parts(("paper", "adaptive", "greedy_fixed", "grid")) == [
        ("paper", "adaptive"), ("greedy_fixed",), ("grid",)]
    assert _parts(("greedy_fixed",)) == [("greedy_fixed",)]
    assert _parts(("adaptive",)) == [("adaptive",)]
    study, base = _small(strategies=["adaptive", "paper", "greedy_fixed"], estimator="learned",
                         plates=1)
    data = study.model_dump(mode="json")
    whole = plate_task(data, base, 0, ("paper", "adaptive", "greedy_fixed"))
    split = [r for part in _parts(("paper", "adaptive", "greedy_fixed"))
             for r in plate_task(data, base, 0, part)]
    assert _strip(whole) == _strip(split)


def test_unreachable_scheduler_fails_fast_naming_the_address():
    t0 = time.monotonic()
    with pytest.raises(SchedulerError, match="tcp://127.0.0.1:9"):
        connect("tcp://127.0.0.1:9", 1, timeout_s=2.0)
    assert time.monotonic() - t0 < 10.0


def test_vmap_equals_loop():
    study, base = _small()
    contexts = [Context.create(study, p, plate_cell(study, base, p))
                for p in (sample_plate(study, i) for i in range(3))]
    model, ev = contexts[0].model, contexts[0].evaluator
    rng = np.random.default_rng(0)
    xy = rng.uniform([-200, -170], [200, 170], (3, 12, 2))
    rows = np.array([model.surface.basis(p[:, 0], p[:, 1]) for p in xy])
    heights = rng.normal(0, 0.05, (3, 12))
    truth = np.array([c.truth_eval for c in contexts])
    touches = np.array([12, 5, 0])
    prior, r = model.belief(model.hyper0), model.hyper0.noise_std_mm**2
    per_v, fin_v = evaluate_vmap(prior, r, ev, rows, heights, truth, touches)
    per_l, fin_l = evaluate_loop(prior, r, ev, rows, heights, truth, touches)
    for a, b in zip(per_v, per_l):
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-12)
    for k in fin_v:
        np.testing.assert_allclose(fin_v[k], fin_l[k], rtol=1e-7, atol=1e-12)


def test_cli_writes_summary_table_and_plots(tmp_path, capsys):
    from adaptive_cal.cli import main

    out = tmp_path / "out.json"
    code = main(["study", str(SMOKE), "--plates", "1", "--strategies", "paper,grid", "--json",
                 str(out), "--out", str(tmp_path / "dir"), "--doc", str(tmp_path / "study.md")])
    assert code == 0
    # progress on stderr: the start line, then each run (in-process: one strategy on one plate)
    # with the time taken; stdout holds the table alone
    std = capsys.readouterr()
    err = std.err.splitlines()
    assert err[0] == "study smoke: 1 plate x 2 strategies = 2 runs in this process (1 worker)"
    assert err[1].startswith("study smoke: 1/2 runs done, ")
    assert err[1].endswith(" s, time left once a plate's strategies are done")
    assert err[2].startswith("study smoke: 2/2 runs done, ") and len(err) == 3
    assert std.out.startswith("bound: ") and "runs done" not in std.out
    summary = json.loads(out.read_text())
    from adaptive_cal import __version__

    assert summary["software"] == f"adaptive-cal {__version__}"  # which code made the figures
    assert summary["written_utc"].endswith("Z")
    for name in ("paper", "grid"):
        s = summary["strategies"][name]
        for key in ("touches_mean", "touches_p90", "robot_time_s_mean", "true_rms_mm_mean",
                    "true_max_mm_mean", "coverage95_mean"):
            assert key in s
        assert s["touches_mean"] >= 1
    assert set(summary["lower_bound"]) >= {"relaxed_touches", "best_integer_touches"}
    for f in ("table.md", "touches_vs_bound.png", "coverage.png", "example_plate.png",
              "plates.jsonl"):
        assert (tmp_path / "dir" / f).exists()
    page = (tmp_path / "study.md").read_text()
    assert "| paper |" in page
    # the page's command is the one that ran (it added --workers 2 and dropped --strategies),
    # and another study's page carries neither the project's provenance nor its targets
    shown = next(line for line in page.splitlines() if line.startswith("OPENBLAS"))
    assert shown == (f"OPENBLAS_NUM_THREADS=1 adaptive-cal study {SMOKE} --json {out} --out "
                     f"{tmp_path / 'dir'} --doc {tmp_path / 'study.md'} --plates 1 --strategies "
                     "paper,grid")
    assert "## Targets" not in page and "63 minutes" not in page
    assert "tilt uniform in +-" in page  # a drawn study says how its plates were drawn


def test_summary_lower_bound_ratios_are_means_of_per_plate_ratios():
    """OUT.json's lower_bound block, from hand-made records: each ratio is the mean over plates of
    adaptive touches over that plate's bound (whole touches, under the stop's hyper-parameters,
    and for the stop's hyper-parameter posterior), plates without a bound are left out."""
    study, _ = _small(strategies=["adaptive"])

    def rec(plate, touches, relaxed, whole, at_stop, greedy, marginal=None):
        bound = {} if relaxed is None else {
            "relaxed_touches": relaxed, "relaxed_whole_touches": whole,
            "relaxed_whole_touches_at_stop": at_stop, "greedy_known_touches": greedy,
            "marginal_whole_touches_at_stop": marginal, "best_integer_touches": None}
        return {"strategy": "adaptive", "plate": plate, "touches": touches, "touches_true": touches,
                "robot_time_s": 1.0, "robot_time_true_s": 1.0, "mean_std_mm": 0.01,
                "true_rms_mm": 0.01, "true_max_mm": 0.02, "coverage95": 0.95, **bound}

    records = [rec(0, 12, 6.8, 7.0, 8.0, 8, 10.0), rec(1, 30, 27.5, 28.0, 28.0, 29, 31.0),
               rec(2, 99, None, None, None, None)]
    lb = summarise(study, records)["lower_bound"]
    assert lb["plates"] == 2
    assert lb["relaxed_touches"] == pytest.approx((6.8 + 27.5) / 2)
    assert lb["adaptive_over_relaxed"] == pytest.approx((12 / 6.8 + 30 / 27.5) / 2)
    assert lb["relaxed_whole_touches"] == pytest.approx(17.5)
    assert lb["adaptive_over_relaxed_whole"] == pytest.approx((12 / 7 + 30 / 28) / 2)
    assert lb["adaptive_over_relaxed_whole_at_stop"] == pytest.approx((12 / 8 + 30 / 28) / 2)
    assert lb["adaptive_over_greedy_known"] == pytest.approx((12 / 8 + 30 / 29) / 2)
    assert lb["marginal_whole_touches_at_stop"] == pytest.approx(20.5)
    assert lb["adaptive_over_marginal_whole_at_stop"] == pytest.approx((12 / 10 + 30 / 31) / 2)
    assert lb["adaptive_below_marginal_plates"] == 1
    assert lb["best_integer_touches"] is None


def test_a_task_refuses_float32_and_names_the_setup():
    """The library sets no global flags: a worker without float64 must fail loudly, not run a
    study in float32."""
    import jax

    from adaptive_cal.study.tasks import plate_task

    study, base = _small(strategies=["adaptive"])
    with jax.enable_x64(False), pytest.raises(RuntimeError, match="worker_setup=use_float64"):
        plate_task(study.model_dump(mode="json"), base, 0, ("adaptive",))
    assert jax.config.jax_enable_x64


def test_adaptive_touches_to_target_count_against_the_target_beside_paper():
    """With `paper` among the strategies the planner runs on to the paper's accuracy where that
    is stricter, but its touches to the true target are counted against the study's target, as
    the grid's and the paper's are: the first trajectory point at or below it. (They were counted
    against the stricter of the two, which charged adaptive more touches than the grid.)"""
    from adaptive_cal.study.tasks import plate_task

    use_float64()
    study, base = _small(strategies=["adaptive", "paper"], estimator="learned")
    data = study.model_dump(mode="json")
    data["bound"].update(mean_std_mm=0.012, true_rms_mm=0.03, max_touches=45)
    recs = {r["strategy"]: r for r in plate_task(data, base, 0, ("adaptive", "paper"))}
    a, p = recs["adaptive"], recs["paper"]
    target = 0.03
    assert p["true_rms_mm"] < target  # the paper's accuracy is the stricter one here
    first = next(t for t, _, rms in a["trajectory"] if rms <= target)
    assert a["touches_true"] == first
    # and the trajectory went on past it towards the paper's accuracy
    assert a["trajectory"][-1][0] > first or a["trajectory"][-1][2] <= p["true_rms_mm"]


def test_a_bound_stop_on_the_last_touch_of_the_budget_pays_no_closure():
    """A run makes no closure touch once the budget is spent (run.loop): a study record stopped
    on the bound at the budget's last touch charges none, one touch earlier it does."""
    from types import SimpleNamespace

    from adaptive_cal.study.strategies import record

    study, _ = _small(strategies=["adaptive"])
    budget = study.bound.max_touches
    ctx = SimpleNamespace(plan=SimpleNamespace(closure=True), study=study,
                          plate=SimpleNamespace(index=0, seed=1, noise_std_mm=0.01),
                          cell=SimpleNamespace(simulation=SimpleNamespace(
                              model_dump=lambda **kw: {})),
                          robot=lambda xy: (float(len(xy)), 0.0),
                          robot_time_s=lambda xy: float(len(xy)))
    final = dict(mean_std_mm=0.01, true_rms_mm=0.01, true_max_mm=0.02, coverage95=0.95)
    xy = np.random.default_rng(0).uniform(-50, 50, (budget, 2))
    traj = [[t, 0.01, 0.01] for t in range(1, budget + 1)]
    at_budget = record(ctx, "adaptive", traj, budget, final, xy, "mean_std_bound", 0.01)
    before = record(ctx, "adaptive", traj, budget - 1, final, xy, "mean_std_bound", 0.01)
    assert (at_budget["touches"], at_budget["closure"]) == (budget, False)
    assert (before["touches"], before["closure"]) == (budget, True)
