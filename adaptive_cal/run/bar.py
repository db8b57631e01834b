"""The run's progress bar (tqdm): touches against the budget, each std against its bound, and
why a run whose bound is met goes on."""
from __future__ import annotations

from adaptive_cal.cell.schema import Cell
from adaptive_cal.hardware.base import ProbeLeftDown


def _progress(enabled: bool, cell: Cell, initial: int):
    if not enabled:
        return None
    from tqdm import tqdm
    return tqdm(total=cell.plan.stop.max_touches, initial=initial, unit="touch",
                desc="touches", dynamic_ncols=True)


#: the stop reasons of a run that met its bound: the bar closes full, not at a share of the budget
BOUND_MET = ("mean_std_bound", "max_std_bound")


def _close_bar(bar, stopped: str | None, error=None) -> None:
    """Close the bar. A run that stopped on its bound ends it full ("bound met" kept): at "26%
    31/120" of the budget it would read as aborted. Any other stop leaves it where the run
    stopped; one that may have left the probe down erases it: the CLI says so first."""
    if stopped in BOUND_MET:
        bar.total = bar.n  # close() draws the bar once more
    if isinstance(error, ProbeLeftDown):
        bar.leave = False  # close() erases it
    bar.close()


def _update(bar, cell: Cell, s, floor: int = 0) -> None:
    """The bar's text: each std with its bound and unit, e.g. ``RMS std 3.9 um / bound 4.0 um``
    (the RMS over the plate: result.json's ``mean_std_mm``), and, once a bound is met, "bound
    met" or why the run goes on (the touch floor, a model the self-checks call inadequate, or
    repeat touches owed)."""
    stop, parts, met = cell.plan.stop, [], False
    for what, value, bound in (("RMS std", s.mean_std_mm, stop.mean_std_mm),
                               ("max std", s.max_std_mm, stop.max_std_mm)):
        parts.append(f"{what} {value * 1e3:.1f} um"
                     + (f" / bound {bound * 1e3:.1f} um" if bound else ""))
        met = met or (bound is not None and value <= bound)
    if met and s.touches < floor:
        parts.append(f"bound met, going on to the touch floor of {floor}")
    elif met and not s.adequate:
        parts.append("bound met, going on: the model's self-checks fail")
    elif met and s.repeats_owed:  # planning.repeats: the learned noise may be the plate
        parts.append(f"bound met, going on: {s.repeats_owed} repeat readings measure the "
                     "probe's own noise")
    elif met:
        parts.append("bound met")
    bar.set_postfix_str(", ".join(parts), refresh=False)
    bar.update(1)
