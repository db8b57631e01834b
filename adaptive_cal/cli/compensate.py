"""``adaptive-cal compensate PROGRAM --map RUN_DIR --out OUT``: a run's map applied to a toolpath
(G-code or a CSV of points): each cutting point's Z raised by the mapped height, long cuts split
to the tolerance, refused where the map's 95 % band exceeds it or where a cut leaves the box
touches could reach (the edge margin: an extrapolation). ``--grid OUT.csv``: the map on a
regular grid instead. The details: docs/compensate.md."""
from __future__ import annotations

import sys


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
    p.add_argument("--heights-only", action="store_true",
                   help="--grid: leave out std_mm and write the height-map format itself "
                        "(x_mm,y_mm,height_mm: a simulation.surface_file or a study's "
                        "plate.surface_files)")
    p.add_argument("--step-mm", type=float, default=None,
                   help="--grid: the grid step, at most this (mm, default 5; the grid's ends "
                        "lie on the workplane's edges)")
    p.add_argument("--tolerance-mm", type=float, default=0.01,
                   help="how closely the output follows the plate (mm): cuts are split until the "
                        "path departs from the map by at most the tolerance less the map's 95 %% "
                        "band, and refused where that band alone exceeds it or where a cut "
                        "leaves the box touches could reach")
    p.add_argument("--frame", choices=("nominal", "corrected"), default="nominal",
                   help="nominal: the whole mapped height (tilt included), for the frame the run "
                        "measured in; corrected: the form alone, for a frame corrected as the run "
                        "proposed (rx, ry and the origin moved by c)")
    p.add_argument("--mark", action="store_true",
                   help="where the band exceeds the tolerance, or a cut leaves the box touches "
                        "could reach (the workplane's edge margin), write the output anyway and "
                        "mark those lines with a comment (a CSV: a compensate_note column)")


def command(args) -> int:
    from pathlib import Path

    from adaptive_cal.cli.common import UserError, refuse_input_as_output

    if args.grid and (args.program or args.out):
        raise UserError("--grid writes the map alone: give either PROGRAM --out OUT or --grid "
                        "OUT.csv, not both")
    if not args.grid and not (args.program and args.out):
        raise UserError("give PROGRAM and --out OUT (the compensated toolpath), or --grid OUT.csv "
                        "(the map on a grid)")
    if args.heights_only and not args.grid:
        raise UserError("--heights-only shapes the --grid file: give --grid OUT.csv with it")
    if args.step_mm is not None and not args.grid:
        raise UserError("--step-mm sets the --grid file's spacing: give --grid OUT.csv with it")
    if args.step_mm is None:
        args.step_mm = 5.0
    check_tolerance(args.tolerance_mm)
    if args.program:  # neither PROGRAM nor the map's run folder is overwritten
        refuse_input_as_output("--out", args.out, [args.program], [args.map])
    if args.grid:
        refuse_input_as_output("--grid", args.grid, [], [args.map])
    if args.program and not Path(args.program).is_file():
        raise UserError(f"PROGRAM {args.program}: "
                        + ("a folder, not a toolpath file" if Path(args.program).is_dir()
                           else "no such file"))

    from adaptive_cal.run.heightmap import load_map

    hmap = load_map(args.map)
    if hmap.unfinished:
        import sys

        print(f"warning: the map in {args.map} is from an unfinished run ({hmap.unfinished}); "
              "its band check below still holds", file=sys.stderr)
    if args.grid:
        return _grid(hmap, args)
    return _program(hmap, args)


def check_tolerance(tolerance_mm: float) -> None:
    """UserError unless --tolerance-mm is finite and at least the written resolution."""
    import math

    from adaptive_cal.cli.common import UserError
    from adaptive_cal.formats.toolpath import DIGITS

    floor = 10.0 ** -DIGITS
    if not (math.isfinite(tolerance_mm) and tolerance_mm > 0):
        raise UserError(f"--tolerance-mm {tolerance_mm}: must be a positive finite number (mm)")
    if tolerance_mm < floor:
        raise UserError(f"--tolerance-mm {tolerance_mm:g}: below {floor:g} mm "
                        f"({floor * 1e3:g} um), the resolution the output's coordinates are "
                        f"written to ({DIGITS} decimals): no output can be held to it")
    if tolerance_mm >= LOOSE_MM:  # valid, but no cut is compensated to half a millimetre
        import sys

        print(f"warning: --tolerance-mm {tolerance_mm:g} is {tolerance_mm * 1e3:g} um -- um "
              f"given as mm? ({tolerance_mm:g} um is {tolerance_mm / 1000:g})", file=sys.stderr)


LOOSE_MM = 0.5  # a tolerance this loose or looser is warned about (check_tolerance)


GRID_CHUNK = 65_536  # nodes evaluated at once (the spline basis of a chunk: a few tens of MB)


def grid_axes(plate_mm, step_mm: float):
    """The --grid axes over the workplane (its ends on the edges, step at most ``step_mm``;
    as ``run.heightmap.HeightMap.grid``), or UserError naming --step-mm when the grid would
    hold more nodes than the height-map reader takes (``formats.heightmap.MAX_NODES``)."""
    import math

    import numpy as np

    from adaptive_cal.cli.common import UserError
    from adaptive_cal.formats.heightmap import MAX_NODES

    if not (math.isfinite(step_mm) and step_mm > 0):
        raise UserError(f"--step-mm {step_mm}: must be a positive finite number (mm)")
    counts = [math.ceil((hi - lo) / step_mm - 1e-9) + 1 for lo, hi in plate_mm]
    nodes = counts[0] * counts[1]
    if nodes > MAX_NODES:
        w, h = (hi - lo for lo, hi in plate_mm)
        least = math.sqrt(w * h / MAX_NODES)
        while (math.ceil(w / least - 1e-9) + 1) * (math.ceil(h / least - 1e-9) + 1) > MAX_NODES:
            least *= 1.001
        raise UserError(f"--step-mm {step_mm:g}: the grid would have {counts[0]:,} x "
                        f"{counts[1]:,} = {nodes:,} nodes; a height map holds at most "
                        f"{MAX_NODES:,} (the reader refuses more): give --step-mm "
                        f"{math.ceil(least * 1000) / 1000:g} or more on this workplane")
    return [np.linspace(lo, hi, n) for (lo, hi), n in zip(plate_mm, counts)]


def grid_text(v):
    """Grid positions as text: rounded to 1e-10 mm, no trailing zeros (a 5 mm step prints 5, not
    5.0000000000000001). Fixed decimals lose a workplane edge such as 30.00004 (4 decimals: 30,
    inside the plate), and the written map then does not cover its own workplane."""
    import numpy as np

    return np.array([np.format_float_positional(x, unique=True, trim="-")
                     for x in np.round(np.asarray(v, float), 10) + 0.0])  # + 0.0: no "-0"


def _grid(hmap, args) -> int:
    import numpy as np

    xs, ys = grid_axes(hmap.plate_mm, args.step_mm)
    xt, yt = grid_text(xs), grid_text(ys)
    height = hmap.height(args.frame)
    columns = "x_mm,y_mm,height_mm" + ("" if args.heights_only else ",std_mm")
    rows = max(1, GRID_CHUNK // len(ys))  # x nodes per chunk (x outer, y inner)
    lo, hi, worst = np.inf, -np.inf, 0.0
    from pathlib import Path

    with Path(args.grid).open("w", encoding="utf-8", newline="\n") as f:
        f.write(columns + "\n")
        for k in range(0, len(xs), rows):
            i, j = (v.ravel() for v in np.meshgrid(np.arange(k, min(k + rows, len(xs))),
                                                   np.arange(len(ys)), indexing="ij"))
            h, s = height(xs[i], ys[j])
            lo, hi, worst = min(lo, h.min()), max(hi, h.max()), max(worst, s.max())
            cells = [xt[i], yt[j], np.char.mod("%.6f", h)]
            cells += [] if args.heights_only else [np.char.mod("%.6f", s)]
            f.write("".join(",".join(r) + "\n" for r in zip(*cells)))
    print(f"wrote {args.grid}: {len(xs) * len(ys)} nodes, frame {args.frame}, height "
          f"{lo:+.4f} .. {hi:+.4f} mm, std at most {worst * 1e3:.2f} um"
          + (" (heights only: the height-map format)" if args.heights_only else ""))
    gap = _between_nodes(height, xs, ys)
    print(f"read bilinearly between its nodes (DESIGN.md), the grid departs from the map by up "
          f"to {gap * 1e3:.2f} um at the cells' centres")
    if gap > args.tolerance_mm:  # an outside audit: --step-mm 1000 left 198 um unsaid
        print(f"warning: that is more than the tolerance {args.tolerance_mm * 1e3:.4g} um: a "
              "finer --step-mm brings it down (about as the step squared)", file=sys.stderr)
    if hmap.reach_mm is not None:
        (x0, x1), (y0, y1) = hmap.reach_mm
        print(f"outside x [{x0:g}, {x1:g}] mm, y [{y0:g}, {y1:g}] mm (the workplane's edge "
              "margin) the map is an extrapolation: no touch could reach there, and no reading "
              f"tested the heights{'' if args.heights_only else ' or the std_mm'} there")
    return 0


def _between_nodes(height, xs, ys, most: int = 40_000) -> float:
    """The largest |bilinear reading of the grid - the map| at the cells' centres (mm), over at
    most ``most`` cells (every k-th along each axis beyond that)."""
    import numpy as np

    step = max(1, int(np.ceil(np.sqrt((len(xs) - 1) * (len(ys) - 1) / most))))
    i, j = (v.ravel() for v in np.meshgrid(np.arange(0, len(xs) - 1, step),
                                           np.arange(0, len(ys) - 1, step), indexing="ij"))
    corners = sum(height(xs[i + a], ys[j + b])[0] for a in (0, 1) for b in (0, 1)) / 4.0
    centre = height(0.5 * (xs[i] + xs[i + 1]), 0.5 * (ys[j] + ys[j + 1]))[0]
    return float(np.max(np.abs(corners - centre))) if len(i) else 0.0


def _checked(path, name: str, T: float) -> str | None:
    """Refuse a program compensate wrote (its heights would be added twice), and a G64 P or Q
    beyond the tolerance (path blending: LinuxCNC leaves the path by up
    to P and merges nearly collinear points -- the splits -- within Q, P where no Q is given:
    the Z between them is then the chord's, not the map's); a warning for one within it, or a
    G64 without P (LinuxCNC then keeps speed however far it leaves the path)."""
    from adaptive_cal.cli.common import UserError

    if path.compensated is not None:
        at, text = path.compensated
        raise UserError(f"{name} line {at}: this program is an output of adaptive-cal compensate "
                        f"({text[:70]}...): compensating it again adds the heights twice; "
                        "compensate the original program")
    if path.blend is None:
        return None
    at, mm = path.blend
    if mm > T:
        raise UserError(f"{name} line {at}: G64 P/Q {mm:g} mm lets the control leave the path, "
                        f"or merge the split points, by up to {mm * 1e3:.4g} um, more than the "
                        f"tolerance {T * 1e3:.4g} um: give G64 P (and Q) at most the tolerance, "
                        "or G61 (exact path)")
    if mm == 0:
        return (f"warning: {name} line {at}: G64 without P -- on LinuxCNC the control then keeps "
                "its speed however far it leaves the path, and the tolerance does not hold; "
                f"give G64 P{T:g} or G61 where that control runs it")
    return (f"warning: {name} line {at}: G64 P/Q {mm:g} mm -- the control may leave the path by "
            f"that much on top of the tolerance {T * 1e3:.4g} um")


def _program(hmap, args) -> int:
    from pathlib import Path

    from adaptive_cal.analysis.compensate import beyond_text, compensate, refusal, under_text
    from adaptive_cal.cli.common import UserError
    from adaptive_cal.formats.toolpath import read_toolpath, write_toolpath
    from adaptive_cal.formats.numbers import count

    name, T = args.program, args.tolerance_mm
    path = read_toolpath(_text(name), name)
    if not path.moves:
        raise UserError(f"{name}: no moves found (G0/G1 with X, Y, Z, or CSV rows x_mm,y_mm,z_mm)")
    blend = _checked(path, name, T)  # a warning to print, or None
    with _bar(len(path.moves)) as bar:
        result = compensate(path, hmap.height(args.frame), hmap.plate_mm, T,
                            top_mm=hmap.top_mm(args.frame), name=name, reach_mm=hmap.reach_mm,
                            keep_outs=hmap.keep_outs, progress=bar.update,
                            touched_xy=hmap.touched_xy)
    marks = {}
    if result.wide or result.beyond or result.under:
        if not args.mark:
            raise UserError(refusal(result.wide, T, name, beyond=result.beyond,
                                    reach_mm=hmap.reach_mm, under=result.under,
                                    keep_outs=hmap.keep_outs))
        by_line = {m.line: m.item for m in path.moves}
        notes = {}
        for w in result.wide:
            notes.setdefault(by_line[w.line], []).append(
                f"95 % band {w.band_mm * 1e3:.1f} um exceeds the tolerance {T * 1e3:.4g} um")
        for b in result.beyond:
            notes.setdefault(by_line[b.line], []).append(
                f"{beyond_text(b.outside_mm)} mm beyond the reach of the touches: the map is "
                "extrapolated")
        for u in result.under:
            notes.setdefault(by_line[u.line], []).append(
                f"over {under_text(u, hmap.keep_outs)}: never touched, a clamp may stand there")
        marks = {item: "adaptive-cal: " + "; ".join(n) for item, n in notes.items()}
    # ASCII, no parentheses: a comment every control reads (a non-ASCII path was copied in)
    where = str(args.map).replace("(", "[").replace(")", "]").encode("ascii", "replace").decode()
    from adaptive_cal.formats.writing import provenance

    made = provenance()  # which code bent the path, and when: a machined part can be traced
    # the tolerance in the file's unit and the terminal's; no nested parentheses
    text = write_toolpath(path, result.pieces, marks, header_comment=(
        f"{made['software']} compensate, {made['written_utc']}: map {where}, frame {args.frame}, "
        f"tolerance {T:g} mm = {T * 1e3:.4g} um"))
    Path(args.out).write_text(text, encoding="utf-8", newline="")
    print(f"{name}: {count(result.cuts, 'cutting move')}, {count(result.rapids, 'rapid')}; "
          f"frame {args.frame}, tolerance {T * 1e3:.4g} um")
    print(f"wrote {args.out}: {result.added} points added by splitting; the path departs from the "
          f"map by at most {result.max_deviation_mm * 1e3:.2f} um at the check samples")
    if result.rapids:
        print(f"rapids raised at their ends (a level one the map tilts: across at the higher "
              f"end's Z, up or down on its own): the plate rises at most "
              f"{max(result.rapid_dip_mm, 0.0) * 1e3:.1f} um above a rapid's travel (the "
              "programmed clearance shrinks by that much along it)")
    far = result.farthest
    if hmap.touched_xy is None:
        print(f"how far the cuts pass from a touch is not known: no readable recording.csv in "
              f"{args.map}")
    elif far is not None:
        print(f"the cuts pass up to {far.distance_mm:.0f} mm from the nearest touch (line "
              f"{far.line}, at x {far.x_mm:.0f}, y {far.y_mm:.0f} mm): a dent or bump narrower "
              "than that can lie there unseen, and the 95 % band does not include one")
    if marks:
        why = " or ".join(w for w, hit in (("the band exceeds the tolerance", result.wide),
                                           ("the map is extrapolated", result.beyond),
                                           ("the cut passes over a keep-out", result.under))
                          if hit)
        print(f"marked {len(marks)} line(s) where {why}: the output is NOT within the tolerance "
              "there")
    if blend:
        print(blend, file=sys.stderr)
    suffix = Path(args.out).suffix.lower()
    kind = {".csv": "csv", ".gcode": "gcode", ".nc": "gcode", ".ngc": "gcode", ".tap": "gcode",
            ".gc": "gcode", ".cnc": "gcode"}.get(suffix, path.kind)
    if kind != path.kind:
        print(f"warning: {args.out} holds {'CSV rows' if path.kind == 'csv' else 'G-code'} "
              f"(the output keeps the program's format), not what its name says",
              file=sys.stderr)
    if path.whole_numbers:
        (line, word), n = path.whole_numbers[0], len(path.whole_numbers)
        print(f"warning: {n} axis word{'s' * (n != 1)} without a decimal point (first: line "
              f"{line}, {word!r}) read as mm, as LinuxCNC, Grbl and Mach3 read them; a Fanuc-type "
              "control without decimal-point programming reads them as thousandths of a mm: run "
              f"{args.out} only on a control that reads them as mm", file=sys.stderr)
    if path.assumed:
        print(f"warning: moves before the program says {' and '.join(path.assumed)}: read as mm "
              "and absolute; a control left in inches or incremental by an earlier program "
              f"would read {args.out}'s heights wrongly: add G21 G90 before the first move",
              file=sys.stderr)
    return 0


def _bar(moves: int):
    """A progress bar over the moves on a terminal, for a program long enough to wait on (the
    map costs about 1 us per check sample, one every 0.5 mm of cut: 100 m of cut, 0.2 s)."""
    from tqdm import tqdm

    return tqdm(total=moves, desc="compensating", unit="move", disable=None if moves > 50_000
                else True, leave=False, dynamic_ncols=True)


def _text(name: str) -> str:
    """PROGRAM's text; UserError naming the file and the line of a byte that is not UTF-8."""
    from pathlib import Path

    from adaptive_cal.cli.common import UserError
    from adaptive_cal.formats.text import not_utf8

    data = Path(name).read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise UserError(f"{not_utf8(name, data)}; save the program as UTF-8 or plain "
                        "ASCII") from None
