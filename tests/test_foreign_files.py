"""Recordings and height maps written by other tools, valid by DESIGN.md but unlike ours (the
conformance audit's F2, F6, F8, F9, F10): RFC 4180 quoting (Python's csv QUOTE_ALL /
QUOTE_NONNUMERIC, R's write.csv), a metadata value we cannot parse, an unknown column named
twice, numbers Python's ``float`` takes but no CSV writer means (``5_1.0``, Arabic-Indic
digits), map coordinates written to 0.1 mm. Oracle: the same file written plainly."""
import numpy as np
import pytest

from adaptive_cal.formats.heightmap import HEADER, HeightMapError, parse_heightmap
from adaptive_cal.formats.recording import RecordingError, read_recording
from adaptive_cal.formats.table import TableError
from adaptive_cal.formats.writing import repair_cut_row

MAGIC = "# adaptive-cal recording v1"
XY = [(x, y) for y in (-150, -50, 50, 150) for x in (-200, -100, 0, 100, 200)]


def _rows():
    """20 touches on a plane tilted 0.01 mm/mm in x; rows 3 and 8 are placeholders (reading
    9.99) flagged rejected/gated: fusing them would tilt the plane by degrees."""
    flags = {3: "rejected;stroke_end", 8: "gated", 9: "retake"}
    out = []
    for i, (x, y) in enumerate(XY):
        reading = 9.99 if i in (3, 8) else 5.0 + 0.01 * x + 0.0005 * np.sin(i)
        out.append([str(i), f"{3.0 * i:.3f}", str(x), str(y), "0", f"{reading:.6f}",
                    flags.get(i, "")])
    return out


HEAD = ["seq", "t_s", "x_mm", "y_mm", "z_mm", "reading_mm", "flags"]


def _write(path, head, rows, meta=("# probe_zero_mm: 5.0",), quote=lambda c: c, nl="\n"):
    lines = [MAGIC, *meta, ",".join(quote(c) for c in head)]
    lines += [",".join(quote(c) for c in r) for r in rows]
    path.write_bytes((nl.join(lines) + nl).encode("utf-8"))
    return path


def _same(a, b):
    for col in ("seq", "t_s", "x_mm", "y_mm", "z_mm", "reading_mm"):
        assert np.array_equal(getattr(a, col), getattr(b, col), equal_nan=True), col
    assert a.flags == b.flags and a.fused.tolist() == b.fused.tolist()


def _quote_all(c):
    return '"' + c.replace('"', '""') + '"'


def _quote_text(c):  # QUOTE_NONNUMERIC: numbers bare, text (and empty) quoted
    try:
        float(c)
        return c
    except ValueError:
        return _quote_all(c)


# --- F2, F6: quoted fields ----------------------------------------------------------------

@pytest.mark.parametrize("quote", [_quote_all, _quote_text], ids=["QUOTE_ALL", "NONNUMERIC"])
@pytest.mark.parametrize("nl", ["\n", "\r\n", "\r"])
def test_quoted_fields_read_as_the_plain_file(tmp_path, quote, nl, capsys):
    """A quoted flags cell "rejected;stroke_end" was read as the words '"rejected' and
    'stroke_end"' and the placeholder row FUSED; a quoted header was 'lacking' its columns."""
    plain = read_recording(_write(tmp_path / "plain.csv", HEAD, _rows()))
    quoted = read_recording(_write(tmp_path / "quoted.csv", HEAD, _rows(), quote=quote, nl=nl))
    _same(quoted, plain)
    assert quoted.fused.tolist() == [i not in (3, 8) for i in range(20)]
    assert quoted.meta["probe_zero_mm"] == "5.0"
    assert "unknown flag" not in capsys.readouterr().err


def test_empty_quoted_flags_are_no_flags(tmp_path, capsys):
    rows = [r[:6] + ['""'] for r in _rows()]
    rec = read_recording(_write(tmp_path / "r.csv", HEAD, rows))
    assert rec.flags == (frozenset(),) * 20 and rec.fused.all()
    assert capsys.readouterr().err == ""


def test_a_note_with_commas_quotes_and_line_breaks_is_one_field(tmp_path):
    """R's write.csv quotes a note holding a comma; a doubled quote is a quote; a quoted field
    may hold a line break (RFC 4180) -- and every later error still names its own line."""
    head = HEAD + ["note"]
    rows = [r + [n] for r, n in zip(_rows(), ['"touched, then re-zeroed"', '"5"" gauge, ok"',
                                              '"two\nlines, here"'] + ["plain"] * 17)]
    path = _write(tmp_path / "r.csv", head, rows)
    rec = read_recording(path)
    _same(rec, read_recording(_write(tmp_path / "plain.csv", HEAD, _rows())))
    text = path.read_text().splitlines()
    # the note of row 2 spans lines 6 and 7: row 5 is on line 10
    assert text[9].startswith("5,")
    text[9] = text[9].replace("5,15.000", "5,abc", 1)
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(RecordingError, match=r"r\.csv:10: column t_s: 'abc' is not a number"):
        read_recording(path)


def test_quoting_faults_are_refused_naming_the_line(tmp_path):
    rows = _rows()
    rows[4][6] = '"gated"x'  # text after the closing quote
    with pytest.raises(RecordingError, match=r"r\.csv:8: not a CSV row"):
        read_recording(_write(tmp_path / "r.csv", HEAD, rows))
    rows = _rows()
    rows[17][6] = '"rejected'  # a quote never closed: the rest of the file would be one field
    with pytest.raises(RecordingError, match=r"q\.csv:21: a quoted field opened on this line is "
                       "not closed by the end of the file"):
        read_recording(_write(tmp_path / "q.csv", HEAD, rows))
    rows = _rows()
    rows[5][6] = '"a, b"'  # the comma inside quotes is no field separator
    rows[6] = rows[6][:6]  # a field missing: its line is named as before
    with pytest.raises(RecordingError, match=r"s\.csv:10: 6 fields, the header \(line 3\) has 7$"):
        read_recording(_write(tmp_path / "s.csv", HEAD, rows))


def test_metadata_lines_between_quoted_rows_and_a_quote_in_an_unquoted_field(tmp_path):
    rows = [",".join(r) for r in _rows()]
    rows.insert(5, "# operator: \"Ann\", shift 2")
    rows[9] = rows[9].replace("gated", '5" gauge')  # row 8  # a quote inside a bare field is text
    path = tmp_path / "r.csv"
    path.write_text("\n".join([MAGIC, ",".join(f'"{h}"' for h in HEAD)] + rows) + "\n")
    rec = read_recording(path)
    assert rec.meta["operator"] == '"Ann", shift 2' and len(rec) == 20
    assert '5" gauge' in rec.flags[8]


def test_a_cut_quoted_row_is_kept_only_when_whole(tmp_path):
    """The cut-row repair (run --resume) keeps another tool's quoted last row that only lacks its
    newline, as the reader reads it, and drops one cut inside its quotes (kept in .cut.txt)."""
    path = _write(tmp_path / "r.csv", HEAD, _rows(), quote=_quote_all)
    whole = path.read_bytes()
    path.write_bytes(whole[:-1])
    assert repair_cut_row(path) is None and path.read_bytes() == whole
    path.write_bytes(whole[:-5])  # ... ,"9.990000","rejec
    cut = path.read_bytes()
    # a reader leaves it out as the repair would (until 2026-11-29 it refused the file), and
    # leaves the file as it is
    assert len(read_recording(path)) == 19 and path.read_bytes() == cut
    repair_cut_row(path)
    assert len(read_recording(path)) == 19
    assert (tmp_path / "r.cut.txt").exists()


def test_a_quoted_table_reads_as_the_plain_one_with_its_lines(tmp_path):
    rows = [[r[2], r[3], r[5], r[6]] for r in _rows()]
    head = ["x_mm", "y_mm", "reading_mm", "flags"]
    plain, quoted = tmp_path / "p.csv", tmp_path / "q.csv"
    plain.write_text("\n".join(",".join(r) for r in [head] + rows) + "\n")
    quoted.write_text("\n".join(",".join(_quote_all(c) for c in r) for r in [head] + rows) + "\n")
    a, b = read_recording(plain), read_recording(quoted)
    assert np.array_equal(a.reading_mm, b.reading_mm) and a.flags == b.flags
    assert b.fused.tolist() == [i not in (3, 8) for i in range(20)]


# --- F9: metadata we cannot parse, an unknown column named twice -----------------------------

@pytest.mark.parametrize("value", ["5.0 mm", "unknown", "", "nan", "5_0"])
def test_a_probe_zero_we_cannot_parse_is_said_once_and_ignored(tmp_path, capsys, value):
    path = _write(tmp_path / "r.csv", HEAD, _rows(), meta=(f"# probe_zero_mm: {value}",))
    rec = read_recording(path)
    assert "probe_zero_mm" not in rec.meta and len(rec) == 20
    err = capsys.readouterr().err
    assert err.count("probe_zero_mm") == 1
    assert f"{path}:2: metadata probe_zero_mm: {value!r} is not a number (mm); ignored" in err


@pytest.mark.parametrize("value", ["1e300", "inf", "-2000"])
def test_a_probe_zero_beyond_the_limit_is_still_refused(tmp_path, value):
    path = _write(tmp_path / "r.csv", HEAD, _rows(), meta=(f"# probe_zero_mm: {value}",))
    with pytest.raises(RecordingError, match=r"r\.csv:2: probe_zero_mm"):
        read_recording(path)


def test_an_unknown_column_named_twice_is_ignored_a_known_one_refused(tmp_path):
    rows = [r + ["a", "b"] for r in _rows()]
    rec = read_recording(_write(tmp_path / "r.csv", HEAD + ["note", "note"], rows))
    assert len(rec) == 20 and "note" not in rec.extra
    rows = [r + ["21.0", "21.5"] for r in _rows()]
    for name in ("temp_c", "round", "x_mm"):
        with pytest.raises(RecordingError, match=rf"header names column\(s\) {name} more than once"):
            read_recording(_write(tmp_path / "r.csv", HEAD + [name, name], rows))


# --- F10: numbers Python's float takes but no CSV writer means --------------------------------

@pytest.mark.parametrize("column, value", [("reading_mm", "5_1.0"), ("reading_mm", "\u0665.\u0661"),
                                           ("x_mm", "\u0661\u0662"), ("t_s", "1_0")])
def test_underscores_and_non_ascii_digits_are_not_numbers(tmp_path, column, value):
    rows = _rows()
    rows[2][HEAD.index(column)] = value
    with pytest.raises(RecordingError) as e:
        read_recording(_write(tmp_path / "r.csv", HEAD, rows))
    assert str(e.value) == f"{tmp_path / 'r.csv'}:6: column {column}: {value!r} is not a number"


def test_a_table_refuses_them_too(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("x_mm,y_mm,reading_mm\n0,0,5.0\n1,0,5_1.0\n")
    with pytest.raises(TableError, match=r"t\.csv:3: column reading_mm: '5_1.0' is not a number"):
        read_recording(path)
    path.write_text("x_mm,y_mm,reading_mm,flags\n0,0,5.0,outlier=0_5\n")
    with pytest.raises(TableError, match="outlier probability"):
        read_recording(path)


# --- F8 and F10: height maps -----------------------------------------------------------------

XS, YS = np.linspace(-225, 225, 19), np.linspace(-185, 185, 15)  # y step 26.4286 mm


def _map_text(fmt="{!r}", header=HEADER, quote=False):
    lines = [header]
    for x in XS:
        for y in YS:
            cells = [fmt.format(float(x)), fmt.format(float(y)), f"{1e-3 * x - 2e-3 * y + 1e-5 * x * y:.9g}"]
            lines.append(",".join(f'"{c}"' for c in cells) if quote else ",".join(cells))
    return "\n".join(lines) + "\n"


def test_coordinates_written_to_a_tenth_of_a_mm_are_the_regular_grid():
    """-185.0, -158.6, -132.1, ...: the writer's round-off (0.05 mm of a 26.4 mm step) was
    refused as 'not a regular grid' ('26.4 mm apart, the grid's spacing is 26.4286 mm')."""
    exact = parse_heightmap(_map_text(), "exact")
    rounded = parse_heightmap(_map_text("{:.1f}"), "rounded")
    assert rounded.y_mm.shape == (15,) and rounded.y_mm[1] == -158.6
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-225, 225, 500), rng.uniform(-185, 185, 500)
    # heights within the surface's slope (< 0.005) times the round-off (0.05 mm)
    assert np.abs(rounded(x, y) - exact(x, y)).max() < 0.005 * 0.05


def test_an_irregular_grid_names_its_nodes_and_spacings_with_digits_that_differ():
    xs = np.array([0.0, 10.0, 20.0, 31.0, 40.0])  # 31 lies 1 mm (1/10 of the step) off
    text = HEADER + "\n" + "\n".join(f"{x},{y},0" for x in xs for y in (0, 5)) + "\n"
    with pytest.raises(HeightMapError) as e:
        parse_heightmap(text, "m")
    assert "not a regular grid: x_mm nodes 20 and 31 are 11 mm apart, the grid's spacing is " \
           "10 mm" in str(e.value)
    ys = np.array([0, 26.43, 52.86, 85])  # spacing 28.3333; 52.86 lies 3.8 mm off (> 1.42)
    text = HEADER + "\n" + "\n".join(f"{x},{y},0" for x in (0, 1) for y in ys) + "\n"
    with pytest.raises(HeightMapError) as e:
        parse_heightmap(text, "m")
    assert "y_mm nodes 52.86 and 85 are 32.14 mm apart, the grid's spacing is 28.3333 mm" \
        in str(e.value)


@pytest.mark.parametrize("header", ["x_mm, y_mm, height_mm", '"x_mm","y_mm","height_mm"',
                                    "\ufeffx_mm ,y_mm,height_mm "])
@pytest.mark.parametrize("quote", [False, True])
def test_a_header_with_spaces_or_quotes_and_quoted_values_read_as_plain(header, quote):
    plain = parse_heightmap(_map_text(), "plain")
    other = parse_heightmap(_map_text(header=header, quote=quote), "other")
    for a, b in ((plain.x_mm, other.x_mm), (plain.y_mm, other.y_mm), (plain.z_mm, other.z_mm)):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("value", ["5_1.0", "\u0665.\u0661"])
def test_a_map_refuses_underscores_and_non_ascii_digits(value):
    lines = _map_text().splitlines()
    lines[4] = lines[4].rsplit(",", 1)[0] + "," + value
    with pytest.raises(HeightMapError, match=f"m, line 5: height_mm must be a finite number, got "
                       f"{value!r}"):
        parse_heightmap("\n".join(lines) + "\n", "m")


def test_a_blank_or_nan_reading_on_a_row_flagged_not_fused_is_read_as_not_taken(tmp_path):
    """Another tool writes a failed reading as NaN or blank on a row it flags invalid: read as
    this tool writes one (0, flagged nonfinite, not fused), not a refusal of the whole file (an
    outside audit). Unflagged, a NaN is still refused naming its line."""
    from adaptive_cal.formats.recording import RecordingError, read_recording

    rows = [f"{i},{i:.1f},{x},{y},0,{5.0 + 0.001 * x:.6f}," for i, (x, y) in
            enumerate([(-100, -50), (0, -50), (100, -50), (-100, 50), (0, 50), (100, 50)])]
    rows[2] = "2,2.0,100,-50,0,nan,invalid;rejected"
    rows[4] = "4,4.0,0,50,0,,Rejected"
    text = "# adaptive-cal recording v1\nseq,t_s,x_mm,y_mm,z_mm,reading_mm,flags\n"
    (tmp_path / "r.csv").write_text(text + "\n".join(rows) + "\n")
    rec = read_recording(tmp_path / "r.csv")
    assert rec.fused.tolist() == [True, True, False, True, False, True]
    assert rec.reading_mm[2] == 0.0 and "nonfinite" in rec.flags[2] and "nonfinite" in rec.flags[4]
    rows[2] = "2,2.0,100,-50,0,nan,"
    (tmp_path / "r.csv").write_text(text + "\n".join(rows) + "\n")
    with pytest.raises(RecordingError, match=r"r\.csv:5: column reading_mm: 'nan' is not a finite"):
        read_recording(tmp_path / "r.csv")
