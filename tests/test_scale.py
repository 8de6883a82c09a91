"""Sharded batch estimation on 4 host devices gives the same results as on one device
(float64, to 1e-9: float32 differs by vectorisation rounding, see jaxpose/scale.py).
Runs in a subprocess: the device count is fixed when JAX starts."""

import os
import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    import jaxpose as jp
    from jaxpose.scale import batch_mesh, estimate_sharded
    assert len(jax.devices()) == 4, jax.devices()
    config = jp.Config.fast(max_points=512, population=8, generations=6, local_steps=10)
    rng = np.random.default_rng(0)
    base = rng.uniform(-1, 1, (400, 3)) * [0.4, 0.25, 0.1] + [0, 0, 5]
    problems = []
    for i in range(6):  # 6 pairs: not a multiple of 4, so padding is exercised
        R = jp.rotation(0.02 * i, -0.01 * i, 0.03)
        curr = jp.Cloud.from_points(base @ np.asarray(R).T)
        problems.append(jp.Problem.build(jp.Cloud.from_points(base), curr, config))
    problems = jax.tree.map(lambda *xs: jnp.stack(xs), *problems)
    keys = jax.random.split(jax.random.key(0), 6)
    four = estimate_sharded(problems, config, keys, batch_mesh())
    one = estimate_sharded(problems, config, keys, batch_mesh(jax.devices()[:1]))
    assert batch_mesh().size == 4 and four.params.shape == (6, 6)
    np.testing.assert_allclose(np.asarray(four.params), np.asarray(one.params), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.asarray(four.status), np.asarray(one.status))
    np.testing.assert_allclose(np.asarray(four.hard), np.asarray(one.hard), rtol=0, atol=1e-12)
    print("OK", np.asarray(four.status).tolist())
    """
)


def test_four_host_devices_match_one():
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "OK" in out.stdout
