"""Hessian covariance of a displacement (issue 7)."""

import jax
import numpy as np
from conftest import PAPER_CAPACITIES, T_PAPER, paper_rotation

import jaxpose as jp
from jaxpose._search import local_refine
from jaxpose._uncertainty import covariance, curvature, nees

CONFIG = jp.Config.fast(capacities=PAPER_CAPACITIES)  # fixed capacities: the tests share one compile


def test_curvature_at_the_optimum_is_positive_definite_and_matches_finite_differences(paper_clouds):
    problem = jp.Problem.build(paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"], CONFIG)
    R1, R2 = paper_rotation("previous"), paper_rotation("variant2")
    truth = jp.true_displacement(problem.frame, R1, T_PAPER, R2, T_PAPER)
    p = local_refine(problem, CONFIG, truth).params
    H = np.asarray(curvature(p, problem))
    np.testing.assert_allclose(H, H.T, rtol=1e-9, atol=1e-9 * np.abs(H).max())
    assert np.linalg.eigvalsh(H).min() > 0
    # Second difference of −f along the first angle, with a step of 0.01° (radians).
    h, e = np.radians(0.01), np.eye(6)[0]
    f = lambda q: -float(jp.soft_score(q, problem))  # noqa: E731
    fd = (f(p + h * e) - 2 * f(p) + f(p - h * e)) / h**2
    assert abs(fd - H[0, 0]) < 0.05 * abs(H[0, 0])
    sigma = np.asarray(covariance(p, problem, 2.0))
    np.testing.assert_allclose(sigma @ H, 2.0 * np.eye(6), atol=1e-6 * np.abs(sigma @ H).max())
    error = jax.numpy.asarray([1e-3, -2e-3, 0.0, 1e-3, 0.0, -1e-3])
    assert np.isclose(float(nees(error, sigma)), float(error @ H @ error) / 2.0, rtol=1e-6)
