"""The form kernel as a hyper-parameter (``gaussian.kernels``, ``prior.learned_belief``): each
kernel's evidence by Laplace's method against brute-force quadrature of the hyper-posterior,
the learned belief as the evidence-weighted mixture of the kernels' beliefs, and the kernel
kept in a saved belief."""
import numpy as np
import pytest

from adaptive_cal.gaussian import belief as bl
from adaptive_cal.gaussian import prior as pr
from test_places import _plan


def _readings(model, kernel, seed, n=60):
    rng = np.random.default_rng(seed)
    a = bl.sample(model.belief(pr.Hyper(0.006, 60.0, 0.004, kernel)), rng, 1)[0]
    xy = np.stack([rng.uniform(-200, 200, n), rng.uniform(-160, 160, n)], 1)
    rows = model.surface.basis(xy[:, 0], xy[:, 1])
    return rows, rows @ a + 0.004 * rng.standard_normal(n)


def _brute_log_evidence(model, rows, y, kernel, centre, half=2.5, nodes=15):
    """log of the integral of exp(-f) over log theta by the midpoint rule on a cube of
    +-``half`` e-folds about ``centre`` (the hyper-prior keeps it finite beyond)."""
    padded = pr._padded(rows, y)
    args = padded + pr._model_args(model) + (pr._padded_weights(padded[2].shape[0]),)
    vg = pr._value_and_grad(kernel)
    g = np.linspace(-half, half, nodes)
    vals = np.array([-float(vg(centre + np.array([a, b, c]), *args)[0])
                     for a in g for b in g for c in g])
    top = vals.max()
    return top + np.log(np.exp(vals - top).sum() * (g[1] - g[0]) ** 3)


@pytest.mark.parametrize("true_kernel, seed", [("se", 1), ("m52", 2)])
def test_each_kernels_laplace_evidence_agrees_with_brute_force_quadrature(true_kernel, seed):
    """Laplace's log evidence per kernel and the log ratio that weighs them, against the
    midpoint rule on 15^3 nodes in log theta. On these two plates: each 0.32-0.39 nats below
    the quadrature (the midpoint rule's and Laplace's shares alike for both kernels), the
    ratio within 0.03. Over 8 other plates of 60 readings the ratio differed by up to 1.2
    nats from a 21^3 quadrature (a skewed length-scale posterior under the squared
    exponential), mostly under 0.15: the kernels' weights are good to a factor of about 3."""
    model = _plan().model
    rows, y = _readings(model, true_kernel, seed)
    laplace, brute = {}, {}
    for k in ("se", "m52"):
        points, laplace[k] = pr._laplace(model, rows, y, None, True, None, None, None, k)
        assert all(h.kernel == k for h, _ in points)
        brute[k] = _brute_log_evidence(model, rows, y, k, np.log(points[0][0].theta))
        assert laplace[k] == pytest.approx(brute[k], abs=1.0)
    assert (laplace["m52"] - laplace["se"]) == pytest.approx(brute["m52"] - brute["se"],
                                                             abs=0.3)


def test_the_learned_belief_is_the_kernels_mixture_weighed_by_evidence():
    model = _plan().model
    rows, y = _readings(model, "m52", 3)
    belief, points = pr.learned_belief(model, rows, y)
    fits = {k: pr._laplace(model, rows, y, None, True, np.ones(len(y)), None, None, k)
            for k in model.kernels}
    z = np.array([fits[k][1] for k in model.kernels])
    share = dict(zip(model.kernels, np.exp(z - z.max()) / np.exp(z - z.max()).sum()))
    assert set(h.kernel for h, _ in points) == set(model.kernels)  # neither under 1e-3 here
    assert sum(w for _, w in points) == pytest.approx(1.0, abs=1e-12)
    for k in model.kernels:  # each kernel's points carry its evidence share
        assert sum(w for h, w in points if h.kernel == k) == pytest.approx(share[k], rel=1e-6)
    assert points[0][0].kernel == max(share, key=share.get)  # the heaviest kernel's MAP first
    assert points[0][0].theta == pytest.approx(fits[points[0][0].kernel][0][0][0].theta,
                                               rel=1e-6)
    mixed = bl.mixture([bl.condition(model.belief(h), rows, y, h.noise_std_mm**2)
                        for h, _ in points], [w for _, w in points])
    np.testing.assert_allclose(belief.mean, mixed.mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(belief.cov, mixed.cov, rtol=0, atol=1e-14)


@pytest.mark.parametrize("ratio, kept", [(1 / 10, {"se", "m52"}), (1 / 30, {"se"})])
def test_a_kernel_outside_occams_window_is_left_out(monkeypatch, ratio, kept):
    """Evidence ratios either side of 1/``OCCAM_RATIO`` (each kernel's fit as computed, its log
    evidence set): the weaker kernel is kept at 1/10 with its share, left out at 1/30."""
    model = _plan().model
    rows, y = _readings(model, "se", 4)
    laplace = pr._laplace

    def fixed(*args):
        points, _ = laplace(*args)
        return points, (0.0 if args[-1] == "se" else np.log(ratio))
    monkeypatch.setattr(pr, "_laplace", fixed)
    _, points = pr.learned_belief(model, rows, y)
    weights = pr.kernel_weights(points)
    assert set(weights) == kept and sum(weights.values()) == pytest.approx(1.0, abs=1e-12)
    if "m52" in kept:
        assert weights["m52"] == pytest.approx(ratio / (1 + ratio), rel=1e-9)


def test_a_saved_belief_keeps_its_kernel():
    from adaptive_cal.formats.npz import saved_hyper

    assert saved_hyper({"hyper": np.array([0.01, 80.0, 0.004]),
                        "kernel": np.array("m52")}) == pr.Hyper(0.01, 80.0, 0.004, "m52")
    # a belief.npz from before the kernel was saved: the squared exponential
    assert saved_hyper({"hyper": np.array([0.01, 80.0, 0.004])}).kernel == "se"


def test_the_report_names_the_kernel_with_each_kernels_weight():
    from adaptive_cal.report.sections import _kernels

    assert pr.kernel_weights([(pr.Hyper(1, 2, 3, "se"), 0.5), (pr.Hyper(1, 3, 3, "m52"), 0.2),
                              (pr.Hyper(1, 2, 4, "se"), 0.3)]) == pytest.approx(
        {"se": 0.8, "m52": 0.2})
    assert pr.kernel_weights(()) == {}
    assert _kernels({"kernel": "m52", "kernel_weights": {"se": 0.3, "m52": 0.7}}) == \
        "Matern-5/2 (weights Matern-5/2 0.70, squared exponential 0.30)"
    assert _kernels({"kernel": "se", "kernel_weights": {"se": 1.0}}) == "squared exponential"
