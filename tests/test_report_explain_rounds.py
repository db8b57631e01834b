"""The report's explain section says what the terminal says: the rounds' flatness in um with
the test of "plate unchanged" named as such, and the verdict none said once."""
import json
import subprocess
import sys

from adaptive_cal.report.explain_page import explain_section

from helpers import ROOT

CHENG = ROOT / "adaptive_cal" / "data" / "cheng2025"


def test_rounds_and_verdict_in_the_report(tmp_path):
    out = tmp_path / "explain.json"
    subprocess.run([sys.executable, "-m", "adaptive_cal.cli", "explain",
                    str(CHENG / "round0_initial.csv"), str(CHENG / "round1_first_correction.csv"),
                    "--robot", str(ROOT / "configs" / "cheng2025-cell.yaml"), "--json", str(out)],
                   check=True, capture_output=True, text=True)
    html = explain_section(tmp_path)
    assert "Rounds: flatness (least squares) 541.7 -&gt; 596.0 um" in html
    assert "test of &quot;plate unchanged&quot;" in html and "p = 0.082" in html
    assert "--compare" in html  # where the interval of the change is
    findings = json.loads(out.read_text())
    findings["verdict"] = "none"
    out.write_text(json.dumps(findings))
    html = explain_section(tmp_path)
    assert html.count("no left-out effect is supported by the data") <= 1
