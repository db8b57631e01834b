"""JSON files a run or an analysis wrote (result.json, explain's OUT.json), read back with the
file named in any error: a file cut short or edited by hand says which file and where."""
from __future__ import annotations

import json
import os


def read_json(path: str | os.PathLike):
    """The parsed contents of ``path``; ValueError naming the file, the line and the column
    when it is not JSON or not UTF-8 (a missing file raises FileNotFoundError as usual)."""
    with open(path, "rb") as f:
        raw = f.read()
    try:
        return json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e.msg} at line {e.lineno}, column "
                         f"{e.colno}); was it cut short or edited?") from None
