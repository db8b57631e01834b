"""What explain's verdict line says: verdict none's probability is none's own posterior (prior
1/2), so 0.51 is "the data could not tell", not a coin toss between effects."""
from adaptive_cal.report.explain_text import verdict_lines


def _none(p):
    return {"verdict": "none", "verdict_probability": p, "ambiguous_with": [],
            "threshold": {"log_bayes_factor": 1.0},
            "candidates": [{"effect": "form", "log_bayes_factor": -0.2}]}


def test_a_clean_null_says_what_its_probability_means_on_one_line():
    head = verdict_lines(_none(0.514))[0]
    assert head.startswith("verdict: none (probability 0.51 that no library effect is present")
    assert "prior is 1/2" in head and "0.5 means the data could not tell" in head
    assert "not that an effect is likely" in head and "\n" not in head


def test_a_named_effect_keeps_its_plain_probability():
    rep = {**_none(0.97), "verdict": "form"}
    assert verdict_lines(rep)[0] == "verdict: form (probability 0.97)"
