"""Sharded batch estimation on 4 host devices, and across two processes joined by
`jax.distributed`, gives the same results as on one device (float64, to 1e-9: float32
differs by vectorisation rounding, see jaxpose/scale.py). Runs in subprocesses: the device
count and the distributed runtime are fixed when JAX starts."""

import os
import socket
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from jaxpose._scale import estimate_sharded

PROBLEMS = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    import jaxpose as jp

    def make_batch():
        config = jp.Config.fast(
            search=jp.GlobalSearch(population=8, generations=6),
            refine=jp.Refine(max_steps=10),
            capacities=jp.Capacities(max_points=512),
        )
        rng = np.random.default_rng(0)
        base = rng.uniform(-1, 1, (400, 3)) * [0.4, 0.25, 0.1] + [0, 0, 5]
        problems = []
        for i in range(6):  # 6 pairs: not a multiple of 4 (or of 2 hosts' devices), so padding is exercised
            R = jp.rotation(0.02 * i, -0.01 * i, 0.03)
            curr = jp.Cloud.from_points(base @ np.asarray(R).T)
            problems.append(jp.Problem.build(jp.Cloud.from_points(base), curr, config))
        problems = jax.tree.map(lambda *xs: jnp.stack(xs), *problems)
        return problems, config, jax.random.split(jax.random.key(0), 6)
    """
)

SCRIPT = (
    textwrap.dedent(
        """
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    import jaxpose as jp
    from jaxpose._scale import batch_mesh, estimate_sharded
    assert len(jax.devices()) == 4, jax.devices()
    """
    )
    + PROBLEMS
    + textwrap.dedent(
        """
    problems, config, keys = make_batch()
    four = estimate_sharded(problems, config, keys, batch_mesh())
    one = estimate_sharded(problems, config, keys, batch_mesh(jax.devices()[:1]))
    assert batch_mesh().size == 4 and four.params.shape == (6, 6)
    np.testing.assert_allclose(np.asarray(four.params), np.asarray(one.params), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.asarray(four.status), np.asarray(one.status))
    np.testing.assert_allclose(np.asarray(four.hard), np.asarray(one.hard), rtol=0, atol=1e-12)
    print("OK", np.asarray(four.status).tolist())
    """
    )
)


@pytest.mark.slow
def test_four_host_devices_match_one():
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=4", "JAX_PLATFORMS": "cpu"}
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "OK" in out.stdout


TWO_HOSTS = (
    textwrap.dedent(
        """
    import sys, jax
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(f"localhost:{sys.argv[2]}", num_processes=2, process_id=int(sys.argv[1]))
    assert jax.process_count() == 2 and len(jax.devices()) == 2
    from jaxpose._scale import estimate_sharded
    """
    )
    + PROBLEMS
    + textwrap.dedent(
        """
    problems, config, keys = make_batch()
    result = estimate_sharded(problems, config, keys)  # default mesh: both processes' devices
    np.savez(sys.argv[3], params=np.asarray(result.params), status=np.asarray(result.status))
    """
    )
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_processes_with_jax_distributed_match_one(tmp_path):
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    port = str(_free_port())
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", TWO_HOSTS, str(i), port, str(tmp_path / f"host{i}.npz")],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    for proc in procs:
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err[-3000:]
    scope = {}
    exec(PROBLEMS, scope)  # the same batch, here on one device
    problems, config, keys = scope["make_batch"]()
    one = estimate_sharded(problems, config, keys)
    for i in range(2):
        host = np.load(tmp_path / f"host{i}.npz")
        np.testing.assert_allclose(host["params"], np.asarray(one.params), rtol=0, atol=1e-9)
        np.testing.assert_array_equal(host["status"], np.asarray(one.status))
