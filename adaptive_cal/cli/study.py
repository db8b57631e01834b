"""``adaptive-cal study STUDY.yaml --json OUT.json [--out DIR] [--scheduler ADDRESS]``: the same
synthetic plates under every strategy, a lower bound on touches, tables and plots.

Plates finished are appended to DIR/plates.jsonl (or OUT.json's name + .plates.jsonl) as they
finish; an interrupted study keeps them and a rerun skips them.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path


def add_arguments(p) -> None:
    p.add_argument("study", help="study file (YAML), e.g. configs/study-tilts.yaml")
    p.add_argument("--json", required=True, metavar="OUT.json", help="summary (JSON)")
    p.add_argument("--out", metavar="DIR", help="per-plate records, table (markdown) and plots")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler (tcp://host:port); workers need OPENBLAS_NUM_THREADS=1")
    p.add_argument("--workers", type=int, default=0,
                   help="run on a Dask LocalCluster of N worker processes (0: in-process)")
    p.add_argument("--plates", type=int, help="override the study's number of plates")
    p.add_argument("--strategies", help="override the study's strategies (comma separated)")
    p.add_argument("--doc", metavar="PAGE.md", help="write the study page (docs/study.md)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override one study key, e.g. --set bound.true_rms_mm=0.01 (YAML value)")
    p.add_argument("--quiet", action="store_true", help="no progress line")


def command(args) -> int:
    from adaptive_cal.study.config import load_study
    from adaptive_cal.study.runner import connect, run_study, summarise

    study, base = load_study(args.study)
    if args.plates:
        study = study.model_copy(update={"plates": args.plates})
    if args.strategies or args.set:
        import yaml

        from adaptive_cal.cell.schema import ConfigError
        from adaptive_cal.study.config import check_feasible, parse_study
        from adaptive_cal.cell.schema import parse_cell

        data = study.model_dump(mode="json")
        if args.strategies:
            data["strategies"] = [s.strip() for s in args.strategies.split(",") if s.strip()]
        for item in args.set:
            key, sep, value = item.partition("=")
            if not sep:
                raise ConfigError(f"--set {item!r}: expected KEY=VALUE")
            *path, leaf = key.split(".")
            node = data
            for part in path:
                if not isinstance(node.get(part), dict):
                    raise ConfigError(f"--set {key}: {part!r} is not a block of the study file")
                node = node[part]
            node[leaf] = yaml.safe_load(value)
        study = parse_study(data, "overrides")
        check_feasible(study, parse_cell(base), "overrides")
    out_json = Path(args.json)
    out_dir = Path(args.out) if args.out else None
    checkpoint = (out_dir / "plates.jsonl" if out_dir
                  else out_json.with_name(out_json.name + ".plates.jsonl"))
    client = None
    if args.scheduler or args.workers:
        client = connect(args.scheduler, max(args.workers, 1))
    t0 = time.monotonic()

    def progress(done: int, total: int) -> None:
        if not args.quiet:
            print(f"\rstudy {study.name}: {done}/{total} tasks, {time.monotonic() - t0:.0f} s",
                  end="", file=sys.stderr, flush=True)

    try:
        records = run_study(study, base, checkpoint, client=client, progress=progress)
    finally:
        if client is not None:
            client.close()
    if not args.quiet:
        print(file=sys.stderr)
    summary = summarise(study, records)
    summary["wall_s"] = round(time.monotonic() - t0, 1)
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    if out_dir:
        from adaptive_cal.study.report import write_report

        write_report(study, summary, records, base, out_dir)
    from adaptive_cal.study.report import table, write_doc

    if args.doc:
        write_doc(Path(args.doc), study, summary, study_file=args.study, json_file=args.json,
                  out_dir=args.out or str(out_json.parent), base=base,
                  plates_arg=f"--plates {args.plates}" if args.plates else "")
    print(table(summary))
    return 0
