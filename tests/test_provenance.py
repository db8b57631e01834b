"""A measurement can be traced to the code that made it: ``adaptive-cal --version``, a run's
recording says which version started it and when (UTC), result.json which version wrote its
figures and when; a resume appends rows and leaves the recording's header as it was."""
import datetime
import json

import pytest
import yaml

from adaptive_cal import __version__
from adaptive_cal.cell.schema import load_cell, load_yaml
from adaptive_cal.cli import main
from adaptive_cal.formats.recording import read_recording
from adaptive_cal.report.html import _made, render
from adaptive_cal.run import session

from helpers import SIM_CELL


def _utc(text: str) -> datetime.datetime:
    assert text.endswith("Z"), text
    return datetime.datetime.strptime(text, "%Y-%m-%dT%H:%M:%SZ").replace(
        tzinfo=datetime.timezone.utc)


def test_version_is_printed(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"adaptive-cal {__version__}"


def test_recording_and_result_say_which_version_made_them_and_when(tmp_path):
    before = datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0)
    data = load_yaml(SIM_CELL)
    data["plan"]["stop"]["max_touches"] = 12
    out = tmp_path / "run"
    out.mkdir()
    (out / "cell.yaml").write_text(yaml.safe_dump(data))  # as `run --out` copies it (the report)
    cell = load_cell(out / "cell.yaml")
    session.run(cell, out, progress=False, max_new_touches=5)  # cut short: resumed below
    meta = read_recording(out / "recording.csv").meta
    assert meta["software"] == f"adaptive-cal {__version__}"
    started = _utc(meta["started_utc"])
    first = json.loads((out / "result.json").read_text())
    assert first["software"] == f"adaptive-cal {__version__}"
    now = datetime.datetime.now(datetime.timezone.utc)
    assert before <= started <= _utc(first["written_utc"]) <= now
    head = (out / "recording.csv").read_text().split("seq,", 1)[0]

    session.run(cell, out, resume=True, progress=False)
    text = (out / "recording.csv").read_text()
    assert text.startswith(head) and text.count("# started_utc:") == 1  # the header as it was
    assert len(read_recording(out / "recording.csv")) > 5
    again = json.loads((out / "result.json").read_text())
    assert _utc(again["written_utc"]) >= _utc(first["written_utc"])
    # the report's first lines say it too
    page = render(out)
    assert (f"Recorded with adaptive-cal {__version__}, started "
            f"{started:%Y-%m-%d %H:%M:%S} UTC.") in page


def test_a_recording_without_it_gets_no_such_sentence():
    assert _made({}) == ""
    assert _made({"software": "other-tool 2"}) == " Recorded with other-tool 2."
