"""A recording as other programs hand it back (an outside audit, 2026-11-29): saved again by a
spreadsheet (every row as wide as the widest, text cells quoted, a second BOM), cut by a crash
in its last row's last number, or not text at all. Each is read as the plain file, or refused
saying what it is."""
import gzip
import io
import zipfile

import numpy as np
import pytest

from adaptive_cal.cli import main
from adaptive_cal.formats.recording import read_recording
from adaptive_cal.formats.spread import unspread

META = ["# adaptive-cal recording v1", "# cell: audit", "# probe_zero_mm: 5.0"]
HEADER = "seq,t_s,x_mm,y_mm,z_mm,reading_mm"


def _rows(n=12):
    rng = np.random.default_rng(3)
    out = []
    for k in range(n):
        x, y = rng.uniform(-200, 200), rng.uniform(-160, 160)
        out.append(f"{k},{3.2 * k:.3f},{x:.4f},{y:.4f},0.0000,{5 + 0.01 * x - 0.004 * y:.6f}")
    return out


def _write(path, lines, end="\n", bom=""):
    path.write_bytes((bom + end.join(lines) + end).encode("utf-8"))
    return path


def _same(a, b):
    assert np.array_equal(a.seq, b.seq) and np.allclose(a.reading_mm, b.reading_mm)
    assert a.meta.get("probe_zero_mm") == b.meta.get("probe_zero_mm") == "5.0"


def test_an_excel_save_reads_as_the_plain_file(tmp_path):
    plain = read_recording(_write(tmp_path / "plain.csv", META + [HEADER] + _rows()))
    wide = [m + ",,,,," for m in META] + [HEADER] + _rows()[:6] + [",,,,,"] + _rows()[6:]
    _same(plain, read_recording(_write(tmp_path / "excel.csv", wide, "\r\n", "\ufeff")))


def test_quoted_text_cells_and_a_second_bom_read_as_the_plain_file(tmp_path):
    plain = read_recording(_write(tmp_path / "plain.csv", META + [HEADER] + _rows()))
    quoted = [f'"{m}"' for m in META] + ['"' + '","'.join(HEADER.split(",")) + '"'] + _rows()
    _same(plain, read_recording(_write(tmp_path / "lo.csv", quoted)))
    _same(plain, read_recording(_write(tmp_path / "bom2.csv", META + [HEADER] + _rows(),
                                       bom="\ufeff\ufeff")))


@pytest.mark.parametrize("line, want", [
    ("# adaptive-cal recording v1,,,,,,,", "# adaptive-cal recording v1"),
    ('"# flags: ok","gated",,', "# flags: ok,gated"), (",,,,,", ""), (" ; ;", ""),
    ("\ufeff\ufeff# cell: a", "# cell: a"), ('0,"1.0",2', '0,"1.0",2')])
def test_unspread(line, want):
    assert unspread(line) == want


def test_a_last_number_cut_by_a_crash_is_left_out_and_said(tmp_path, capsys):
    rows = _rows()
    cut = rows[-1][:rows[-1].rindex(".") + 3]  # 6 decimals cut to 2, and no line end
    p = tmp_path / "cut.csv"
    p.write_text("\n".join(META + [HEADER] + rows[:-1] + [cut]))
    rec = read_recording(p)
    assert len(rec.seq) == len(rows) - 1
    assert "fewer decimals than the row before's" in capsys.readouterr().err
    p.write_text("\n".join(META + [HEADER] + rows))  # whole, only its line end missing
    assert len(read_recording(p).seq) == len(rows)
    # a writer that trims zeros (5.1 after 5.123) and ends without a line end: nothing says cut
    trimmed = [r.rsplit(",", 1)[0] + "," + repr(float(r.rsplit(",", 1)[1])) for r in rows]
    trimmed[-1] = trimmed[-1].rsplit(",", 1)[0] + ",5.1"
    p.write_text("\n".join(META + [HEADER] + trimmed))
    assert len(read_recording(p).seq) == len(rows)


@pytest.mark.parametrize("kind, data", [
    # mtime=0: the same bytes on every xdist worker (a timestamp made their test ids differ)
    ("gzip-compressed", gzip.compress(b"# adaptive-cal recording v1\n", mtime=0)),
    ("zip archive", None), ("PNG image", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR")])
def test_a_file_that_is_no_text_is_named_for_what_it_is(tmp_path, capsys, kind, data):
    if data is None:
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as z:
            z.writestr("xl/workbook.xml", "<workbook/>")
        data = buf.getvalue()
    p = tmp_path / "rec.csv"
    p.write_bytes(data)
    assert main(["flatness", str(p)]) == 2
    err = capsys.readouterr().err
    assert f"not CSV text but a {kind}" in err and "UTF-16" not in err


def test_a_copy_saved_again_is_not_a_second_round(tmp_path, capsys):
    a = _write(tmp_path / "a.csv", META + [HEADER] + _rows())
    b = _write(tmp_path / "b.csv", META + [HEADER] + _rows(), "\r\n", "\ufeff")
    assert main(["flatness", str(a), "--compare", str(b)]) == 2
    assert "the same recording as" in capsys.readouterr().err


def test_an_upper_case_header_is_refused_saying_why(tmp_path, capsys):
    p = _write(tmp_path / "u.csv", META + [HEADER.upper()] + _rows())
    assert main(["flatness", str(p)]) == 2
    assert "column names are lower case" in capsys.readouterr().err


def test_a_long_quoted_note_is_an_ignored_column_like_an_unquoted_one(tmp_path):
    note = "x" * 200_000
    rows = [r + f',"{note}"' for r in _rows()]
    rec = read_recording(_write(tmp_path / "n.csv", META + [HEADER + ",note"] + rows))
    assert len(rec) == 12


def test_a_height_map_with_a_height_beyond_a_metre_is_refused_by_line():
    from adaptive_cal.formats.heightmap import HeightMapError, parse_heightmap
    rows = ["x_mm,y_mm,height_mm"] + [f"{x},{y},{5000.0 if (x, y) == (10, 0) else 0.01}"
                                      for x in (0, 10, 20) for y in (0, 10)]
    with pytest.raises(HeightMapError, match="line 4: height_mm '5000.0' is beyond"):
        parse_heightmap("\n".join(rows))


@pytest.mark.parametrize("first", ["-100,-100,-0.5", "x,y,z"])
def test_a_point_table_without_its_header_says_what_is_missing(first):
    from adaptive_cal.formats.toolpath import ToolpathError, read_toolpath
    with pytest.raises(ToolpathError, match="needs the header line x_mm,y_mm,z_mm"):
        read_toolpath(first + "\n1,2,3\n")


def test_flatness_picks_one_round_of_a_file_with_several(tmp_path, capsys):
    """An outside audit (2026-11-29): a valid recording whose optional round column holds two
    rounds (as the reference cell's data are) was refused by flatness, which explain reads."""
    rows = [r + ",0" for r in _rows()] + [
        f"{12 + k},{r.split(',', 2)[1]},{r.split(',', 3)[2]},{r.split(',', 4)[3]},0.0000,"
        f"{float(r.rsplit(',', 1)[1]) + 0.01:.6f},1" for k, r in enumerate(_rows())]
    p = _write(tmp_path / "two.csv", META + [HEADER + ",round"] + rows)
    one = _write(tmp_path / "one.csv", META + [HEADER] + _rows())
    assert main(["flatness", str(p)]) == 2 and "flatness --round R" in capsys.readouterr().err
    assert main(["flatness", str(p), "--round", "3"]) == 2
    assert "no such round; its round column holds 0, 1" in capsys.readouterr().err
    assert main(["flatness", str(p), "--round", "0", "--json"]) == 0
    import json
    picked = json.loads(capsys.readouterr().out)
    assert main(["flatness", str(one), "--json"]) == 0
    alone = json.loads(capsys.readouterr().out)
    assert picked["flatness_mm"] == alone["flatness_mm"] and "(round 0)" in picked["recording"]
    # two rounds of one file compare as two rounds; the same round twice is refused
    assert main(["flatness", str(p), "--round", "0", "--compare", str(p),
                 "--compare-round", "1", "--json"]) == 0
    change = json.loads(capsys.readouterr().out)["change"]["least_squares"]["measured_mm"]
    assert abs(change) < 1e-9  # round 1 is round 0 raised by 10 um everywhere: no change
    assert main(["flatness", str(p), "--round", "0", "--compare", str(p),
                 "--compare-round", "0"]) == 2
    assert main(["flatness", str(p), "--compare-round", "1"]) == 2
