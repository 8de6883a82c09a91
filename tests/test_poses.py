import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

import jaxpose as jp
from jaxpose import _poses as poses


def random_pose(rng):
    R = np.asarray(jaxlie.SO3.sample_uniform(jax.random.key(int(rng.integers(1e9)))).as_matrix())
    return R, rng.normal(size=3)


@pytest.mark.parametrize("seed", range(5))
def test_frame_moved_by_true_displacement_is_the_moved_target_frame(seed):
    rng = np.random.default_rng(seed)
    R1, t1 = random_pose(rng)
    R2, t2 = random_pose(rng)
    A, O = random_pose(rng)  # a frame n attached to the target at the previous instant
    frame = jp.PlaneFrame(jnp.asarray(O), jnp.asarray(A), jnp.zeros(3), jnp.asarray(10), jnp.asarray(0))
    p = jp.true_displacement(frame, R1, t1, R2, t2)
    # Frame ν per DECISIONS: axes G^c_n G(θ,φ,ψ), origin O_n + G^c_n (x, y, z).
    axes_nu = A @ np.asarray(jp.rotation(*p[:3]))
    origin_nu = O + A @ np.asarray(p[3:])
    # The same frame carried along by the target: x ↦ R_rel x + t_rel with R_rel = R2 R1ᵀ.
    R_rel = R2 @ R1.T
    t_rel = t2 - R_rel @ t1
    np.testing.assert_allclose(axes_nu, R_rel @ A, atol=1e-12)
    np.testing.assert_allclose(origin_nu, R_rel @ O + t_rel, atol=1e-12)
    # Inverse conversion.
    R_back, t_back = jp.motion_from_displacement(O, A, p)
    np.testing.assert_allclose(np.asarray(R_back), R_rel, atol=1e-12)
    np.testing.assert_allclose(np.asarray(t_back), t_rel, atol=1e-12)


def test_relative_motion_agrees_with_jaxlie():
    """relative_motion is T2 ∘ T1⁻¹ in SE(3), computed independently with jaxlie."""
    rng = np.random.default_rng(1)
    (R1, t1), (R2, t2) = random_pose(rng), random_pose(rng)

    def se3(R, t):
        return jaxlie.SE3.from_rotation_and_translation(jaxlie.SO3.from_matrix(jnp.asarray(R)), jnp.asarray(t))

    x = rng.normal(size=(4, 3))
    R, t = poses.relative_motion(R1, t1, R2, t2)
    want = jax.vmap((se3(R2, t2) @ se3(R1, t1).inverse()).apply)(jnp.asarray(x))
    np.testing.assert_allclose(np.asarray(x @ np.asarray(R).T + np.asarray(t)), np.asarray(want), atol=1e-12)
