"""``adaptive-cal report DIR``: one self-contained HTML page of a run (figures embedded)."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("run_dir", metavar="DIR", help="a run folder written by 'adaptive-cal run --out "
                   "DIR' (result.json, recording.csv, cell.yaml, belief.npz; explain.json and "
                   "explain's figures are included when present)")
    # "%(default).0s" prints nothing; it stops the formatter appending "(default: None)"
    p.add_argument("--out", metavar="FILE.html", default=None,
                   help="where to write the page (default: DIR/report.html)%(default).0s")


def command(args) -> int:
    from pathlib import Path

    from adaptive_cal.cli.common import UserError

    given = Path(args.run_dir)
    if given.is_file():
        raise UserError(f"{given} is a file; report wants the run folder: adaptive-cal report "
                        f"{given.parent}")
    from adaptive_cal.report.html import write

    path = write(args.run_dir, args.out)
    print(f"wrote {path}")
    return 0
