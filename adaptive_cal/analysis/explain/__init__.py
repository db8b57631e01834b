"""``explain``: locate where a simulation and real recordings differ, name the physics left out,
model it and show the fit improve (issue 4; docs/explain.md).

Modules: design (features, nominal, nuisance), evidence (marginal likelihood, LOO), candidates
(effect library scored by evidence), intervals and averaging (a searched effect's
parameters averaged over its refined grid: calibrated intervals), suspects (readings that disagree with every model),
locate (mismatch by axis), structure (structure left after the library: the
``unexplained`` verdict), spans (directional identifiability), identify (aliasing and suggested
touches), rounds (flatness change vs noise), params (a candidate's parameters, sds and
intervals), beside (the other candidates judged with the verdict in the model), core (the
pipeline), summary (the explained cell file). The figures are in ``adaptive_cal.report.explain_figures``; the concealed-effect recordings
in ``adaptive_cal.simulation.concealed``. The physics is ``adaptive_cal.effects``.
"""
from adaptive_cal.analysis.explain.core import (THRESHOLD, Explanation, belief_rows, effect_params,
                                               explain, explain_design)
from adaptive_cal.analysis.explain.identify import suggest_touches

__all__ = ["explain", "explain_design", "Explanation", "belief_rows", "effect_params",
           "suggest_touches", "THRESHOLD"]
