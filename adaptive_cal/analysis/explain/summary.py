"""Writing what explain found: the cell file with the winning effect added (the world's edge).

The figures are drawn by ``adaptive_cal.report.explain_figures``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from adaptive_cal import effects
from adaptive_cal.analysis.explain.core import Explanation


def write_cell(explanation: Explanation, cell_data: dict, cell_path: str | Path,
               out_dir: str | Path) -> Path | None:
    """The cell file with the winning effect added to simulation.effects (std in comments)."""
    rep = explanation.findings
    if rep["verdict"] in ("none", "unexplained"):
        return None
    entry = next(e for e in rep["left_out"] if e["effect"] == rep["verdict"])
    params = {k: (v[-1] if isinstance(v, list) else v) for k, v in entry["params"].items()}
    data = dict(cell_data)
    sim = dict(data.get("simulation") or {})
    listed = dict(sim.get("effects") or {})
    known = effects.get(entry["effect"]).param_names
    listed[entry["effect"]] = {k: float(v) for k, v in params.items() if k in known}
    sim["effects"] = listed
    data["simulation"] = sim
    out = Path(out_dir) / f"{Path(cell_path).stem}-explained.yaml"
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"# {Path(cell_path).name} with the effect adaptive-cal explain found added:",
             f"# {entry['summary']}",
             "# standard deviations: " + ", ".join(
                 f"{k} {np.atleast_1d(v)[-1]:.3g}" for k, v in entry["params_std"].items())]
    if entry.get("sharing") == "per_round":
        lines.append("# fitted per round; the last round's values are written")
    out.write_text("\n".join(lines) + "\n" + yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return out
