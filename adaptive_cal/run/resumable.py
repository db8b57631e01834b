"""What a recording must be before ``--resume`` fuses it and moves the robot on its map.

The run that wrote the recording judged every reading before it fused it (``robust.check_touch``:
on the workplane, outside the keep-outs, inside the probe's usable stroke and the workspace's z
range) and saved, with its map, the digest of the rows the map was made from. A resume that
finds otherwise is refused before anything is sent, naming the line -- the recording was edited
by hand, or the cell file is not the one the run used. An outside audit (2026-12-01): a reading
typed outside the workplane, one outside the stroke, x and y swapped in the header, or the
folder's own cell.yaml given another probe zero were all fused without a word (true error 0.3 to
2 mm afterwards, approaches planned on that map), where ``report`` and ``flatness`` refuse the
same recording; a finished run whose recording was edited said "nothing to do".
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from adaptive_cal.formats.recording import Recording, RecordingError
from adaptive_cal.planning.plan import SurveyPlan
from adaptive_cal.planning.robust import check_touch

AGAIN = ("nothing was sent. Replay the recording as it is (adaptive-cal report / flatness "
         "RECORDING --robot CELL), or start a new --out")


def resumable(out: Path, rec: Recording, plan: SurveyPlan, zero_mm: float) -> Recording:
    """``rec`` when a resume may fuse it under ``plan`` (probe zero ``zero_mm``); else
    RecordingError naming the line and what is wrong (module docstring)."""
    from adaptive_cal.report.replay import line_of

    where = rec.path or str(out / "recording.csv")
    try:
        recorded = float(rec.meta.get("probe_zero_mm", "nan"))
    except ValueError:
        recorded = math.nan
    if math.isfinite(recorded) and abs(recorded - zero_mm) > 1e-9:
        raise RecordingError(f"{where}: recorded with probe_zero_mm {recorded:g}, but the cell "
                             f"resumed has probe.zero_mm {zero_mm:g} (its cell.yaml edited since "
                             f"the run?): its heights would change under the map; {AGAIN}")
    for i in np.flatnonzero(rec.fused):
        try:
            check_touch(plan, rec.x_mm[i], rec.y_mm[i], rec.z_mm[i], rec.reading_mm[i])
        except (ValueError, TypeError) as e:
            line, why = line_of(rec.path, int(i)), str(e).replace(": not fused", "")
            raise RecordingError(
                f"{where}{f':{line}' if line else ''}: touch seq {int(rec.seq[i])} is a fused "
                f"reading that the run could not have fused under this cell: "
                f"{why} (the recording edited by hand, or "
                f"another cell file?); {AGAIN}") from None
    _same_rows_as_the_map(out, rec, where)
    return rec


def _same_rows_as_the_map(out: Path, rec: Recording, where: str) -> None:
    """The rows the saved map (belief.npz) was made from are the recording's first rows, as
    they were (``formats.writing.rows_digest``)."""
    from adaptive_cal.formats.npz import read_npz
    from adaptive_cal.formats.writing import rows_digest

    if not (out / "belief.npz").is_file():
        return
    saved = read_npz(out / "belief.npz", keys=(), optional=("touches", "recording_sha256"))
    if "touches" not in saved or "recording_sha256" not in saved:
        return
    n = int(saved["touches"])
    if len(rec) < n or rows_digest(rec, n) != str(saved["recording_sha256"]):
        raise RecordingError(
            f"{where} is not the recording the map saved beside it (belief.npz) was made from: "
            f"it holds {len(rec)} rows, the map {n}"
            f"{'' if len(rec) < n else ', with other values in them'} (a row deleted or edited "
            f"since?); a resume would go on from another map than the run's; {AGAIN}")
