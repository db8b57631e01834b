"""Seeded mutants of a v1 recording, one family at a time (the recording fuzzer's generator).

``mutant(rng, text)`` returns (family, bytes). Every family is a way a recording really gets
damaged or hand-edited: cut by a crash, edited in a spreadsheet (BOM, CRLF, ``;``), columns
dropped, renamed or added, numbers replaced by text, NaN, inf or absurd values, rows reordered,
the wrong file given. Whether a mutant is still a valid recording is for the reader to decide.
"""
import random

BAD_NUMBERS = ["nan", "NaN", "inf", "-inf", "Infinity", "1e300", "-1e300", "9999", "1e5", "-1e5",
               "1e309", "0x10", "1,5", "", " ", "abc", "5.0.1", "--1", "1e", "∞", "١٢"]


def _split(text):
    lines = text.splitlines()
    head = [i for i, l in enumerate(lines) if l.strip() and not l.startswith("#")][0]
    return lines, head


def _join(lines, nl="\n"):
    return (nl.join(lines) + nl).encode("utf-8")


def _rows(lines, head):
    return list(range(head + 1, len(lines)))


def _set_cell(lines, i, col, value):
    cells = lines[i].split(",")
    cells[col] = value
    lines[i] = ",".join(cells)


def f_truncate_rows(rng, lines, head):
    return _join(lines[: head + 1 + rng.randrange(len(lines) - head)])


def f_cut_last_line(rng, lines, head):
    data = _join(lines)
    return data[: len(data) - 1 - rng.randrange(1, len(lines[-1]) + 1)]


def f_cut_anywhere(rng, lines, head):
    data = _join(lines)
    return data[: rng.randrange(len(data))]


def f_missing_column(rng, lines, head):
    col = rng.randrange(len(lines[head].split(",")))
    for i in range(head, len(lines)):
        cells = lines[i].split(",")
        del cells[col]
        lines[i] = ",".join(cells)
    return _join(lines)


def f_extra_column(rng, lines, head):
    name = rng.choice(["temp_c", "j1_deg", "note", "reading_mm", "x_mm", "seq", "", "flags2"])
    value = rng.choice(["1.5", "text", "", "nan", "1e300"])
    for i in range(head, len(lines)):
        lines[i] += "," + (name if i == head else value)
    return _join(lines)


def f_renamed_column(rng, lines, head):
    cells = lines[head].split(",")
    col = rng.randrange(len(cells))
    cells[col] = rng.choice([cells[col].upper(), cells[col] + "_", " " + cells[col], "x", "",
                             cells[col].replace("_mm", "_um")])
    lines[head] = ",".join(cells)
    return _join(lines)


def f_reordered_columns(rng, lines, head):
    order = list(range(len(lines[head].split(","))))
    rng.shuffle(order)
    for i in range(head, len(lines)):
        cells = lines[i].split(",")
        lines[i] = ",".join(cells[j] for j in order)
    return _join(lines)


def f_non_numeric(rng, lines, head):
    i = rng.choice(_rows(lines, head))
    col = rng.randrange(6)
    _set_cell(lines, i, col, rng.choice(BAD_NUMBERS))
    return _join(lines)


def f_huge_value(rng, lines, head):
    for _ in range(rng.choice([1, 1, 3])):
        i = rng.choice(_rows(lines, head))
        col = rng.randrange(1, 6)
        _set_cell(lines, i, col, rng.choice(["1e300", "-1e300", "9999", "1e5", "-1e5", "1e12",
                                             "1e-300", "-0", "5e-324"]))
    return _join(lines)


def f_bad_seq(rng, lines, head):
    rows = _rows(lines, head)
    i = rng.choice(rows[1:])
    kind = rng.choice(["duplicate", "decreasing", "negative", "float", "gap", "start100", "huge"])
    prev = lines[i - 1].split(",")[0] if i - 1 > head else "0"
    new = {"duplicate": prev, "decreasing": str(int(prev) - 1), "negative": "-1", "float": "3.5",
           "huge": "99999999999999999999999"}.get(kind)
    if kind == "gap":
        for j in rows[rows.index(i):]:
            _set_cell(lines, j, 0, str(int(lines[j].split(",")[0]) + 7))
    elif kind == "start100":
        for j in rows:
            _set_cell(lines, j, 0, str(int(lines[j].split(",")[0]) + 100))
    else:
        _set_cell(lines, i, 0, new)
    return _join(lines)


def f_encoding(rng, lines, head):
    kind = rng.choice(["bom", "crlf", "bom+crlf", "cr", "latin1", "utf16", "tabs", "spaces"])
    if kind == "bom":
        return b"\xef\xbb\xbf" + _join(lines)
    if kind == "crlf":
        return _join(lines, "\r\n")
    if kind == "bom+crlf":
        return b"\xef\xbb\xbf" + _join(lines, "\r\n")
    if kind == "cr":
        return _join(lines, "\r")
    if kind == "latin1":
        lines.insert(1, "# note: caf\xe9")
        return ("\n".join(lines) + "\n").encode("latin-1")
    if kind == "utf16":
        return ("\n".join(lines) + "\n").encode("utf-16")
    if kind == "tabs":
        return _join([l if l.startswith("#") else l.replace(",", "\t") for l in lines])
    return _join([l if l.startswith("#") else l.replace(",", " , ") for l in lines])


def f_short_file(rng, lines, head):
    kind = rng.choice(["empty", "magic only", "header only", "single row", "two rows",
                       "blank lines", "only comments"])
    if kind == "empty":
        return b""
    if kind == "magic only":
        return _join(lines[:1])
    if kind == "header only":
        return _join(lines[: head + 1])
    if kind == "single row":
        return _join(lines[: head + 2])
    if kind == "two rows":
        return _join(lines[: head + 3])
    if kind == "blank lines":
        return _join([x for l in lines for x in (l, "", "   ")])
    return _join([l for l in lines if l.startswith("#")])


def f_flags(rng, lines, head):
    names = lines[head].split(",")
    if "flags" not in names:
        return _join(lines)
    col = names.index("flags")
    flag = rng.choice(["rejected", "gated", "rejected;retake", "unknown", "gated;surprise"])
    rows = _rows(lines, head)
    chosen = rows if rng.random() < 0.5 else rng.sample(rows, max(1, len(rows) - 3))
    for i in chosen:
        _set_cell(lines, i, col, flag)
    return _join(lines)


def f_field_count(rng, lines, head):
    i = rng.choice(_rows(lines, head))
    lines[i] = lines[i] + ",1" if rng.random() < 0.5 else lines[i].rsplit(",", 1)[0]
    return _join(lines)


def f_geometry(rng, lines, head):
    """Degenerate layouts: every touch at one point, or on one line (tilt not determined)."""
    kind = rng.choice(["one point", "one line x", "one line y", "two points"])
    for n, i in enumerate(_rows(lines, head)):
        if kind != "one line x":
            _set_cell(lines, i, 2, "10.0" if kind != "two points" or n % 2 else "-10.0")
        if kind != "one line y":
            _set_cell(lines, i, 3, "20.0")
    return _join(lines)


def f_junk(rng, lines, head):
    data = bytearray(_join(lines))
    kind = rng.choice(["insert", "overwrite", "whole", "nul"])
    if kind == "whole":
        return bytes(rng.randrange(256) for _ in range(rng.choice([1, 64, 4096])))
    junk = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
    if kind == "nul":
        junk = b"\x00" * len(junk)
    at = rng.randrange(len(data))
    if kind == "overwrite":
        data[at: at + len(junk)] = junk
    else:
        data[at:at] = junk
    return bytes(data)


def f_version(rng, lines, head):
    lines[0] = rng.choice(["# adaptive-cal recording v2", "# adaptive-cal recording v0",
                           "# adaptive-cal recording", "#adaptive-cal recording v1",
                           "# Adaptive-Cal Recording v1", "seq,t_s,x_mm,y_mm,z_mm,reading_mm",
                           "# adaptive-cal recording v1 ", "  # adaptive-cal recording v1"])
    return _join(lines)


def f_metadata(rng, lines, head):
    value = rng.choice(["abc", "nan", "inf", "1e300", "-1e300", "", "5.0 mm", "1e5"])
    kept = [l for l in lines if not l.startswith("# probe_zero_mm")]
    kept.insert(1, f"# probe_zero_mm: {value}")
    return _join(kept)


def f_shuffled_rows(rng, lines, head):
    rows = lines[head + 1:]
    rng.shuffle(rows)
    return _join(lines[: head + 1] + rows)


FAMILIES = {name[2:]: f for name, f in globals().items() if name.startswith("f_")}


def mutant(rng: random.Random, text: str) -> tuple[str, bytes]:
    """(family, file contents) of one seeded mutant of the recording ``text``."""
    family = rng.choice(sorted(FAMILIES))
    lines, head = _split(text)
    return family, FAMILIES[family](rng, lines, head)
