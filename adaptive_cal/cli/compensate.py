"""``adaptive-cal compensate PROGRAM --map RUN_DIR --out OUT``: a run's map applied to a toolpath
(G-code or a CSV of points): each cutting point's Z raised by the mapped height, long cuts split
to the tolerance, refused where the map's 95 % band exceeds it. ``--grid OUT.csv``: the map on a
regular grid instead. The details: docs/compensate.md."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("program", metavar="PROGRAM", nargs="?",
                   help="the toolpath: G-code (G0/G1 with X, Y, Z; G21 mm; G90 absolute) or a CSV "
                        "with the columns x_mm, y_mm, z_mm (more columns are kept)")
    p.add_argument("--map", metavar="RUN_DIR", required=True,
                   help="a run folder written by 'adaptive-cal run --out RUN_DIR' (cell.yaml, "
                        "result.json, belief.npz)")
    p.add_argument("--out", metavar="OUT", help="the compensated toolpath, in PROGRAM's format")
    p.add_argument("--grid", metavar="OUT.csv",
                   help="instead of a toolpath: write the map on a regular grid over the "
                        "workplane, columns x_mm, y_mm, height_mm, std_mm")
    p.add_argument("--step-mm", type=float, default=5.0,
                   help="--grid: the grid step, at most this (mm; the grid's ends lie on the "
                        "workplane's edges)")
    p.add_argument("--tolerance-mm", type=float, default=0.01,
                   help="how closely the output follows the plate (mm): cuts are split until the "
                        "path departs from the map by at most the tolerance less the map's 95 %% "
                        "band, and refused where that band alone exceeds it")
    p.add_argument("--frame", choices=("nominal", "corrected"), default="nominal",
                   help="nominal: the whole mapped height (tilt included), for the frame the run "
                        "measured in; corrected: the form alone, for a frame corrected as the run "
                        "proposed (rx, ry and the origin moved by c)")
    p.add_argument("--mark", action="store_true",
                   help="where the band exceeds the tolerance, write the output anyway and mark "
                        "those lines with a comment (a CSV: a compensate_note column)")


def command(args) -> int:
    from pathlib import Path

    from adaptive_cal.cli.common import UserError

    if args.grid and (args.program or args.out):
        raise UserError("--grid writes the map alone: give either PROGRAM --out OUT or --grid "
                        "OUT.csv, not both")
    if not args.grid and not (args.program and args.out):
        raise UserError("give PROGRAM and --out OUT (the compensated toolpath), or --grid OUT.csv "
                        "(the map on a grid)")
    if not args.tolerance_mm > 0:
        raise UserError(f"--tolerance-mm {args.tolerance_mm}: must be positive (mm)")
    if args.program and Path(args.out).resolve() == Path(args.program).resolve():
        raise UserError(f"--out {args.out} is PROGRAM itself: write the output to another file")
    if args.program and not Path(args.program).is_file():
        raise UserError(f"PROGRAM {args.program}: no such file")

    from adaptive_cal.run.heightmap import load_map

    hmap = load_map(args.map)
    if hmap.unfinished:
        import sys

        print(f"warning: the map in {args.map} is from an unfinished run ({hmap.unfinished}); "
              "its band check below still holds", file=sys.stderr)
    if args.grid:
        return _grid(hmap, args)
    return _program(hmap, args)


def _grid(hmap, args) -> int:
    from adaptive_cal.cli.common import UserError

    try:
        x, y, h, s = hmap.grid(args.step_mm, args.frame)
    except ValueError as e:
        raise UserError(str(e)) from None
    lines = ["x_mm,y_mm,height_mm,std_mm"]
    lines += [f"{a:.4f},{b:.4f},{c:.6f},{d:.6f}" for a, b, c, d in zip(x, y, h, s)]
    from pathlib import Path

    Path(args.grid).write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {args.grid}: {len(x)} nodes, frame {args.frame}, height {h.min():+.4f} .. "
          f"{h.max():+.4f} mm, std at most {s.max() * 1e3:.1f} um")
    return 0


def _program(hmap, args) -> int:
    from pathlib import Path

    from adaptive_cal.analysis.compensate import compensate, refusal
    from adaptive_cal.cli.common import UserError
    from adaptive_cal.formats.toolpath import read_toolpath, write_toolpath

    name, T = args.program, args.tolerance_mm
    path = read_toolpath(Path(name).read_text(encoding="utf-8"), name)
    if not path.moves:
        raise UserError(f"{name}: no moves found (G0/G1 with X, Y, Z, or CSV rows x_mm,y_mm,z_mm)")
    result = compensate(path, hmap.height(args.frame), hmap.plate_mm, T,
                        top_mm=hmap.top_mm(args.frame), name=name)
    marks = {}
    if result.wide:
        if not args.mark:
            raise UserError(refusal(result.wide, T, name))
        by_line = {m.line: m.item for m in path.moves}
        marks = {by_line[w.line]: f"adaptive-cal: 95 % band {w.band_mm * 1e3:.1f} um exceeds the "
                                  f"tolerance {T * 1e3:.1f} um" for w in result.wide}
    where = str(args.map).replace("(", "[").replace(")", "]")
    text = write_toolpath(path, result.pieces, marks, header_comment=(
        f"adaptive-cal compensate: map {where}, frame {args.frame}, tolerance {T:g} mm"))
    Path(args.out).write_text(text, encoding="utf-8", newline="")
    print(f"{name}: {result.cuts} cutting moves, {result.rapids} rapids; frame {args.frame}, "
          f"tolerance {T * 1e3:.1f} um")
    print(f"wrote {args.out}: {result.added} points added by splitting; the path departs from the "
          f"map by at most {result.max_deviation_mm * 1e3:.2f} um at the check samples")
    if result.rapids:
        print(f"rapids raised at their ends, not split: the plate rises at most "
              f"{max(result.rapid_dip_mm, 0.0) * 1e3:.1f} um above a straight rapid (the "
              "programmed clearance shrinks by that much along it)")
    if marks:
        print(f"marked {len(marks)} line(s) where the band exceeds the tolerance: the output is "
              "NOT within the tolerance there")
    return 0
