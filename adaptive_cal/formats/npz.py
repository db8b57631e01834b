"""Arrays a run saved (belief.npz), read back with the file named in any error: a file cut
short, overwritten or from another program says which file and what is wrong with it."""
from __future__ import annotations

import os
import zipfile

import numpy as np

BELIEF_KEYS = ("mean", "cov", "hyper", "knots_x", "knots_y")


def read_npz(path: str | os.PathLike, keys=BELIEF_KEYS) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of the .npz file at ``path`` (no pickled objects); ValueError naming
    the file when it is not an .npz numpy wrote or lacks one of ``keys``."""
    try:
        with np.load(path, allow_pickle=False) as data:
            held = list(data.files)
            arrays = {k: data[k] for k in keys if k in held}
    except FileNotFoundError:
        raise
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise ValueError(f"{path}: not an .npz file adaptive-cal wrote ({e}); was it cut "
                         "short or overwritten?") from None
    except ValueError:  # not an archive numpy reads, or an array of pickled objects
        raise ValueError(f"{path}: not an .npz file adaptive-cal wrote (not a zip archive of plain "
                         "arrays); was it cut short or overwritten?") from None
    missing = [k for k in keys if k not in arrays]
    if missing:
        raise ValueError(f"{path}: no array {missing[0]!r} (it holds "
                         f"{', '.join(held) or 'nothing'}): not a file adaptive-cal wrote")
    return arrays
