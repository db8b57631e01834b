"""Suspect readings: readings that disagree with every model explain fits (a chip under the tip,
a misread) are not physics; they are listed and kept out of the evidence for an effect.

Each reading is either a good one (its error is the reading noise) or, with prior rate
``RATE``, a gross error (the noise plus an error of scale ``SCALE`` noise sds: normal, with a
tenth of it in a Cauchy tail, g below, since a misread can be any size). For
a model M (``none`` or a candidate at its best nonlinear parameters) the odds follow from the
leave-one-out predictive of reading i given the others (a linear smoother: exact shortcut):

    e_i = (y_i - yhat_i) / (1 - h_ii),   var(e_i | good) = v_i / (1 - h_ii),
    B_iM = g(e_i; v_i / (1 - h_ii) + SCALE^2 v_i) / t_nu(e_i; 0, v_i / (1 - h_ii)),

with v_i the noise variance of the other readings (RSS without i and without the readings
already judged suspect, over its degrees of freedom; those are refitted without), never below the probe's stated noise
squared. The models are averaged with their posterior weights w_M (none 1/2, the candidates
sharing the rest, as the verdict):

    P(i gross) = sum_M w_M RATE B_iM / sum_M w_M (RATE B_iM + 1 - RATE),

the exact posterior of the joint (model, reading i good or gross) with the nonlinear parameters
at their best values and the noise plugged in. A reading is a suspect at P >= ``SUSPECT``:
it disagrees with every probable model. A burr that several touches see is explained by the
local_defect model (its predictive from the neighbours carries the bump), so it stays
evidence; a lone spike disagrees with every model, since a bump that one touch carries is not
a local_defect hypothesis (``candidates.nameable_reach``). The judgement is iterated a few times so one suspect neither
inflates the noise nor tilts the fit another is judged against.

The screen (``screened``): score, judge, set the suspects aside, score again. A suspect inside
the fitted bump's reach is judged once more with every model's nonlinear parameters integrated
out (``integrated_log_odds``: the models scored with and without it), since the bump above is
held at the grid point fitted with the reading in; and its state, good or gross, is integrated
out of every candidate's evidence (``mixed_log_bf``): a burr's top touch that is a gross error
with probability 0.6 leaves the bump 0.4 of its weight, where setting it aside left none.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy import special

from adaptive_cal.analysis.explain import masking
from adaptive_cal.analysis.explain.candidates import Candidate, Context, score_candidates
from adaptive_cal.analysis.explain.design import MIN_ROWS_PER_ROUND, Design
from adaptive_cal.analysis.explain.evidence import prior_precision
from adaptive_cal.analysis.tails import LOG_SQRT_2PI, t_logpdf
from adaptive_cal.formats.recording import RecordingError

RATE = 0.005  # prior share of gross errors among the fused readings (the loop's gate and retake
#               already set most aside: rows flagged gated or rejected never reach explain)
SCALE = 20.0  # a gross error's standard deviation in noise sds
TAIL = 0.1  # its share in a Cauchy tail: a misread can be any size (``_gross_logpdf``)
SUSPECT = 0.5  # listed (and kept out of the evidence) at this posterior probability or above
ITERATIONS = 4
MAX_SUSPECT_SHARE = 0.2  # isolated bad readings, not a bad recording: at most this share is set aside


def apart(p: np.ndarray, in_bump: np.ndarray) -> np.ndarray:
    """Indices (in order) of the suspects (P >= ``SUSPECT``) set aside together in one pass:
    every suspect outside the fitted bump's reach (``in_bump``: rows the local_defect
    candidate's column touches), and of those inside it only the most probable. The bump's
    centre was chosen with the spike in the data, so it can make the spike's neighbours look bad;
    they wait for the next pass, which searches the bump again without the spike. Elsewhere
    ``suspect_probability`` already judges each reading with the others' suspects left out of
    the fit, so they go together: a heavy-tailed recording with hundreds of suspects takes a few
    passes, not hundreds of full rescorings."""
    idx = np.flatnonzero(p >= SUSPECT)
    idx = idx[np.argsort(-p[idx], kind="stable")]
    inside = idx[in_bump[idx]]
    return np.sort(np.concatenate([idx[~in_bump[idx]], inside[:1]]))


def predictive(D: np.ndarray, y: np.ndarray, penalty: np.ndarray, keep: np.ndarray):
    """Leave-one-out predictive of every reading from the readings kept (the others out).

    The penalised least squares fit y ~ D coef on the kept rows (penalty: a k x k matrix, zero
    rows for the flat-prior nuisance), q_i = d_i^T A^-1 d_i. A kept reading: e_i / (1 - q_i)
    with variance factor 1 / (1 - q_i) (the exact shortcut); a reading left out: e_i with factor
    1 + q_i. Returns (residual, variance factor, noise variance of the other kept readings,
    their degrees of freedom).
    """
    e, q = masking.penalised_fit(D, y, penalty, keep)
    q_in = np.clip(q, 0.0, 1.0 - 1e-9)
    loo = np.where(keep, e / (1.0 - q_in), e)
    factor = np.where(keep, 1.0 / (1.0 - q_in), 1.0 + q)
    rss = float(np.sum(e[keep] ** 2))
    dof = int(np.count_nonzero(keep)) - float(np.sum(q[keep]))
    rss_i = np.where(keep, rss - e ** 2 / (1.0 - q_in), rss)  # least squares: exact
    dof_i = np.maximum(dof - keep.astype(float), 1.0)
    return loo, factor, np.maximum(rss_i, 0.0) / dof_i, dof_i


def _gross_logpdf(e, scale):
    """A gross error's log density at e: N(0, scale^2) with a Cauchy tail of the same scale
    (weight ``TAIL``). A misread has no size limit: with the normal alone, a reading 500 noise
    sds off was likelier "good" under the good readings' Student-t (its tail ~ e^-(nu + 1))
    than gross, and a 1 mm spike stood as structure while a 0.1 mm one was set aside."""
    z = e / scale
    log_normal = -0.5 * z * z - LOG_SQRT_2PI
    log_cauchy = -np.log(np.pi) - np.log1p(z * z)
    return np.logaddexp(np.log1p(-TAIL) + log_normal, np.log(TAIL) + log_cauchy) - np.log(scale)


def gross_error_log_odds(loo, factor, noise_var, dof, floor_var: float = 0.0):
    """log B_i (module docstring): gross error against a good reading, for one model."""
    v = np.maximum(np.maximum(noise_var, floor_var), 1e-30)
    good = v * factor
    log_good = t_logpdf(loo / np.sqrt(good), dof) - 0.5 * np.log(good)
    return _gross_logpdf(loo, np.sqrt(good + SCALE ** 2 * v)) - log_good


def suspect_probability(models, y, weights, floor_mm: float):
    """P(gross error) per reading (module docstring) and the leave-one-out residual under the
    most probable model.

    ``models``: (D, penalty) per model; ``weights``: their posterior probabilities. Each pass
    refits every model without the readings the last pass judged suspect, so a gross error
    neither inflates the noise nor tilts the fit the others are judged against. Started with
    every reading good, and again from a robust fit's outliers where it has any
    (``masking``: two gross errors hid each other); the start of larger joint posterior wins.
    """
    w = np.asarray(weights, float)
    logw = np.log(np.maximum(w / w.sum(), 1e-300))[:, None]
    p, loo = _judged(models, y, logw, floor_mm, np.zeros(y.size, bool))
    most = int(np.ceil(MAX_SUSPECT_SHARE * y.size))
    start = masking.robust_start(models[0][0], y, floor_mm, most)
    if np.any(start & (p < SUSPECT)):  # the robust fit sees a gross error the screen did not
        p2, loo2 = _judged(models, y, logw, floor_mm, start)
        joint = [masking.log_joint(models, y, logw, s, floor_mm, RATE, _gross_logpdf, SCALE)
                 for s in (p >= SUSPECT, p2 >= SUSPECT)]
        if joint[1] > joint[0]:
            p, loo = p2, loo2
    return p, loo[int(np.argmax(w))]


def _judged(models, y, logw, floor_mm: float, suspect: np.ndarray):
    """The passes of ``suspect_probability`` from the suspects ``suspect``: P(gross error) per
    reading and each model's leave-one-out residuals, of the last pass."""
    for _ in range(ITERATIONS):
        logb, loos = [], []
        for D, pen in models:
            loo, factor, v, dof = predictive(D, y, pen, ~suspect)
            logb.append(gross_error_log_odds(loo, factor, v, dof, floor_mm ** 2))
            loos.append(loo)
        logb = np.array(logb)
        # sum_M w_M RATE B_iM / sum_M w_M (RATE B_iM + 1 - RATE), in logs
        gross = np.logaddexp.reduce(logw + np.log(RATE) + logb, axis=0)
        good = np.logaddexp.reduce(logw + np.log1p(-RATE) + np.zeros_like(logb), axis=0)
        p = np.exp(gross - np.logaddexp(gross, good))
        new = p >= SUSPECT
        if np.array_equal(new, suspect) or np.count_nonzero(~new) <= models[0][0].shape[1] + 1:
            break
        suspect = new
    return p, loos


def model_terms(nuisance: np.ndarray, candidates) -> list[tuple[np.ndarray, np.ndarray]]:
    """(D, penalty) of ``none`` and of each candidate at its best nonlinear parameters."""
    k0 = nuisance.shape[1]
    out = [(nuisance, np.zeros((k0, k0)))]
    for c in candidates:
        k1 = c.columns.shape[1]
        pen = np.zeros((k0 + k1, k0 + k1))
        pen[k0:, k0:] = c.noise_var * prior_precision(c.prior_var)
        out.append((np.hstack([nuisance, c.columns]), pen))
    return out


def log_model_prior(k: int) -> np.ndarray:
    """log prior of none (1/2), then of each of ``k`` candidates (sharing the other half)."""
    return np.concatenate([[-np.log(2.0)], np.full(k, -np.log(2.0) - np.log(max(k, 1)))])


def model_probabilities(cands: list[Candidate]) -> np.ndarray:
    """Posterior over none and the candidates (``log_model_prior``). A log BF that is NaN (an
    exact fit, every reading the nominal, has no finite evidence) counts as 0: no preference."""
    lbf = np.nan_to_num(np.array([0.0] + [c.log_bf for c in cands], float), nan=0.0)
    logp = log_model_prior(len(cands)) + lbf
    return np.exp(logp - logp.max()) / np.exp(logp - logp.max()).sum()


def scored(design: Design, bells=None) -> tuple[Design, Context, list[Candidate]]:
    """Calibrate (tilt, offsets, unknowns), then score every testable candidate (``bells``:
    ``kept_bells``, or None to build them)."""
    ctx = Context.of(design)
    calibrated = design.features.ideal_reading_mm + (design.target - ctx.yt)
    design = design.with_ideal_reading(calibrated)  # probe_gain sees the calibrated indication
    ctx = Context.of(design)
    return design, ctx, score_candidates(ctx, design.untestable, bells)


def kept_bells(design: Design, keep: np.ndarray, built: dict):
    """radius -> the bump search's bells (``defect_regressor_sparse``) of
    ``design.select(keep)``, cut from the whole design's (built once per radius, in ``built``):
    each touch's entries are its own and stored in touch order, so the rows kept give the matrix
    built on them, entry for entry and in the same order (so the same sums)."""
    from scipy import sparse

    from adaptive_cal.effects.plate import defect_regressor_sparse

    index = np.cumsum(keep) - 1

    def bells(radius: float):
        if radius not in built:
            built[radius] = defect_regressor_sparse(design.features, design.geometry, radius)
        S = built[radius]
        if keep.all():
            return S
        on = keep[S.row]
        return sparse.coo_matrix((S.data[on], (index[S.row[on]], S.col[on])),
                                 shape=(int(np.count_nonzero(keep)), S.shape[1]))
    return bells


def gross_log_density(residual: float, noise_var: float) -> float:
    """log g(y_i): a gross error's density at the reading's leave-one-out residual, of scale
    sqrt((1 + SCALE^2) v) (``_gross_logpdf``)."""
    return float(_gross_logpdf(float(residual),
                               np.sqrt((1.0 + SCALE ** 2) * max(float(noise_var), 1e-30))))


def _total(log_z: dict[str, float]) -> float:
    """log sum_M pi_M p(y | M), pi the prior of ``log_model_prior``."""
    z = [log_z["none"]] + [v for name, v in log_z.items() if name != "none"]
    return float(special.logsumexp(np.array(z) + log_model_prior(len(z) - 1)))


def integrated_log_odds(log_z_with: dict, log_z_without: dict, log_gross: float) -> float:
    """log odds that reading i is a gross error with every model's nonlinear parameters (a
    bump's centre and radius) and the noise integrated out: the exact posterior of the joint
    (model, reading good or gross) from the models' evidence with and without the reading,

        sum_M pi_M p(y_-i | M) RATE g(y_i)  :  sum_M pi_M p(y | M) (1 - RATE)

    (``Context.log_marginal``; g: ``gross_log_density``). ``suspect_probability`` holds each
    candidate at the grid point fitted with the reading in: for a bump that two touches carry
    that point is a compromise (grid radii, its bell against the burr's profile) that may fit the
    top touch worst, while bumps elsewhere on the grid that fit the others predict it."""
    return (_total(log_z_without) + log_gross + np.log(RATE)
            - _total(log_z_with) - float(np.log1p(-RATE)))


def mixed_log_bf(log_z_with: dict, log_z_without: dict, log_gross: float) -> dict[str, float]:
    """Each candidate's log BF against none with reading i's state (good, or gross with prior
    RATE) integrated out: log [p(y | M) (1 - RATE) + p(y_-i | M) RATE g(y_i)] less none's. A
    reading that is a gross error with probability 0.6 keeps 0.4 of its weight as evidence,
    instead of none when it is set aside."""
    good, bad = float(np.log1p(-RATE)), float(np.log(RATE)) + log_gross
    mix = {k: float(np.logaddexp(v + good, log_z_without[k] + bad))
           for k, v in log_z_with.items() if k in log_z_without}
    return {k: v - mix["none"] for k, v in mix.items() if k != "none"}


def screened(design: Design):
    """Score, judge every reading against every model, set the suspects aside and score again,
    until no reading is a suspect (``core._screened``). Inside the fitted bump's reach only the
    most probable suspect is judged in a pass (``apart``), once those outside it are set aside,
    and with the bump's centre and radius integrated out (``integrated_log_odds``: the models
    scored without it, which is the next pass's scoring when it goes): below even odds it stays
    evidence (held, judged once). Its state is integrated out of every candidate's evidence
    (``mixed_log_bf``, the difference to the branch taken carried to the end): a bump whose top
    touch is a gross error with probability 0.6 is not reduced to none. Returns (design,
    context, candidates, [(row, probability, leave-one-out residual) of the suspects])."""
    keep, held = np.ones(design.n, bool), np.zeros(design.n, bool)
    found: list[tuple[int, float, float]] = []
    offset: dict[str, float] = {}  # mixed_log_bf less the branch taken, per candidate
    memo: dict[bytes, tuple] = {}
    built: dict[float, object] = {}  # the whole design's bells, per radius (``kept_bells``)

    def score(k: np.ndarray):
        if k.tobytes() not in memo:
            if len(memo) >= 2:  # the current pass and one trial without a reading
                memo.clear()
            memo[k.tobytes()] = scored(design.select(k), kept_bells(design, k, built))
        return memo[k.tobytes()]

    while True:
        d, ctx, cands = score(keep)
        w = model_probabilities(cands)
        p, loo = suspect_probability(model_terms(ctx.nuisance, cands), d.target, w,
                                     design.noise_floor_mm)
        p = np.where(held[keep], 0.0, p)
        room = int(np.ceil(MAX_SUSPECT_SHARE * design.n)) - len(found)
        bump = [np.any(c.columns != 0, axis=1) for c in cands if c.effect == "local_defect"]
        in_bump = bump[0] if bump else np.zeros(p.size, bool)
        batch = apart(p, in_bump)
        batch = batch[np.argsort(-p[batch], kind="stable")][:max(room, 0)]
        if np.any(~in_bump[batch]):
            batch = batch[~in_bump[batch]]  # the one inside waits for a pass without these
        rows, newly = np.flatnonzero(keep), False
        for j in batch[in_bump[batch]]:  # at most one, alone
            best = int(np.argmax(w))
            var = np.exp(ctx.w0) if best == 0 else cands[best - 1].noise_var
            lg = gross_log_density(loo[j], max(var, design.noise_floor_mm ** 2))
            trial = keep.copy()
            trial[rows[j]] = False
            _, ctx_out, cands_out = score(trial)
            lz_in, lz_out = ctx.log_marginal(cands), ctx_out.log_marginal(cands_out)
            p[j] = 1.0 / (1.0 + np.exp(-integrated_log_odds(lz_in, lz_out, lg)))
            branch = {c.effect: c.log_bf for c in (cands if p[j] < SUSPECT else cands_out)}
            for name, lbf in mixed_log_bf(lz_in, lz_out, lg).items():
                offset[name] = offset.get(name, 0.0) + lbf - branch.get(name, lbf)
            if p[j] < SUSPECT:
                held[rows[j]], newly = True, True
                batch = batch[batch != j]
        if not len(batch):
            if newly:
                continue  # the next suspect inside the bump, if any (this scoring again)
            break
        found += [(int(rows[j]), float(p[j]), float(loo[j])) for j in batch]
        keep[rows[batch]] = False
        for r, path in enumerate(design.paths):
            left = int(np.count_nonzero(keep & (design.round_index == r)))
            if left < MIN_ROWS_PER_ROUND:
                seqs = ", ".join(str(int(design.seq[i])) for i, _, _ in found)
                raise RecordingError(
                    f"{path}: {len(found)} reading{'s' * (len(found) != 1)} (seq {seqs}) "
                    f"disagree{'s' * (len(found) == 1)} with every model (suspect); {left} are "
                    f"left in this recording and explain needs at least {MIN_ROWS_PER_ROUND}: "
                    "check the probe and those rows")
    cands = sorted((replace(c, log_bf=c.log_bf + offset.get(c.effect, 0.0)) for c in cands),
                   key=lambda c: -c.log_bf)
    return d, ctx, cands, found
