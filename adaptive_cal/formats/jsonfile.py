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


# what every reader of a run's result.json relies on (report, flatness's unfinished-run note)
RESULT_KEYS = {"stopped_because": str, "touches": int, "tilt": dict, "posterior": dict,
               "flatness_mm": dict, "bound": dict}


def read_result(path: str | os.PathLike) -> dict:
    """A run's result.json (``read_json``), with the keys its readers use checked: ValueError
    naming the file and the first key missing or of the wrong kind (a file from another tool,
    or edited by hand), and where the map can come from instead (its recording and cell file)."""
    result = read_json(path)
    problem = None if isinstance(result, dict) else f"holds a {type(result).__name__}, not an object"
    for key, kind in RESULT_KEYS.items():
        if problem is not None:
            break
        if key not in result:
            problem = f"has no {key!r}"
        elif not isinstance(result[key], kind) or isinstance(result[key], bool):
            problem = f"{key!r} is {json.dumps(result[key])[:40]}, not {kind.__name__}"
    if problem:
        folder = os.path.dirname(os.path.abspath(path))
        raise ValueError(f"{path}: {problem}: not a result.json that 'adaptive-cal run' wrote, or "
                         f"edited since; the map can be rebuilt from the recording: adaptive-cal "
                         f"report {os.path.join(folder, 'recording.csv')} --robot "
                         f"{os.path.join(folder, 'cell.yaml')}")
    return result
