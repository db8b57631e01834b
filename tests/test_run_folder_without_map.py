"""A finished run folder reads without the simulated plate's height map: report, flatness and
compensate read the run's belief, never the simulated truth. The run's cell.yaml names the map
by an absolute path; once the map was moved or the folder copied elsewhere, all three refused
the folder ("cannot read the height map"). ``--resume`` still needs it (it simulates on)."""
import contextlib
import io

import numpy as np
import yaml

from adaptive_cal.cli import main

from helpers import SIM_CELL


def test_report_flatness_and_compensate_read_a_run_whose_map_is_gone(tmp_path):
    gx, gy = np.arange(-225, 226, 25.0), np.arange(-185, 186, 18.5)
    X, Y = np.meshgrid(gx, gy)
    rows = "\n".join(f"{x:g},{y:g},{0.00005 * x:.9f}" for x, y in zip(X.ravel(), Y.ravel()))
    (tmp_path / "plate.csv").write_text("x_mm,y_mm,height_mm\n" + rows + "\n")
    data = yaml.safe_load(SIM_CELL.read_text())
    data["simulation"]["surface_file"] = "plate.csv"
    data["plan"]["stop"] = {"max_touches": 12}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    run = tmp_path / "run"
    quiet = contextlib.redirect_stdout(io.StringIO())
    with quiet:
        assert main(["run", "--robot", str(tmp_path / "cell.yaml"), "--out", str(run),
                     "--no-progress"]) == 1  # 12 touches, the default bound unmet
    (tmp_path / "plate.csv").unlink()
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        assert main(["compensate", "--map", str(run), "--grid", str(tmp_path / "g.csv")]) == 0
        assert main(["report", str(run)]) == 0
        assert main(["flatness", str(run / "recording.csv")]) == 0
    assert (tmp_path / "g.csv").is_file() and (run / "report.html").is_file()
    assert "height map" in err.getvalue() and "is gone" in err.getvalue()
    # --resume simulates on: it needs the map, and says which key names it
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(["run", "--resume", str(run)]) == 2
