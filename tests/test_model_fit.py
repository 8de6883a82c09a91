"""Known-model baseline: the box signed distance and the Levenberg–Marquardt pose fit."""

import jax.numpy as jnp
import jaxlie
import numpy as np

import jaxpose as jp
from jaxpose.evaluation.model_fit import box_distance, fit_model


def test_box_distance_is_the_exact_signed_distance():
    box = jp.targets.Boxes.create([[0.0, 0.0, 0.0]], [[2.0, 1.0, 0.5]])
    points = jnp.array([[0.0, 0.0, 0.0], [1.5, 0.0, 0.0], [1.0, 0.5, 0.25], [2.0, 1.5, 0.0], [0.9, 0.0, 0.0]])
    expected = [-0.25, 0.5, 0.0, np.hypot(1.0, 1.0), -0.1]
    np.testing.assert_allclose(np.asarray(box_distance(points, box)), expected, atol=1e-12)


def test_fit_recovers_the_pose_of_a_known_box_from_a_few_degrees_off(paper_clouds, camera):
    from conftest import T_PAPER, paper_rotation

    R_true = paper_rotation("previous")
    R0 = jaxlie.SO3.exp(jnp.array([0.05, -0.03, 0.02])).as_matrix() @ R_true  # ≈ 3.6° off
    fit = fit_model(paper_clouds["n1", "previous"], jp.targets.n1(), R0, T_PAPER + jnp.array([0.02, -0.01, 0.03]))
    assert bool(fit.converged) and float(fit.rms) < 1e-6
    assert np.degrees(float(jp.rotation_angle(fit.rotation, R_true))) < 1e-3
    np.testing.assert_allclose(np.asarray(fit.translation), np.asarray(T_PAPER), atol=1e-5)
