"""Peak resident memory of `estimate` (issue 6): one full 204 × 204 pair and a vmapped batch
of 64 pairs, default config, each in a fresh process (ru_maxrss after the run, and the same
process's peak before the estimate, i.e. JAX + the clouds, as a baseline). Each case runs
twice with a persistent compilation cache: the first run compiles (XLA's compile memory
counts), the second loads the executable, so its peak is the run's own (what a CLI user with
a warm cache sees).

    uv run python experiments/memory.py  →  results/memory.json
"""

import tempfile

from _common import run_child, write_json

CHILD = r"""
import json, resource, sys
import jax, jax.numpy as jnp
jax.config.update("jax_compilation_cache_dir", sys.argv[2])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
sys.path.insert(0, "experiments")
from _common import paper_cloud
import jaxpose as jp
from jaxpose._estimate import estimate_problem
batch = int(sys.argv[1])
config = jp.Config(capacities=jp.Capacities(max_points=5120))
problem = jp.Problem.build(paper_cloud("n5", "previous"), paper_cloud("n5", "variant 2"), config)
jax.block_until_ready(problem.r_field)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
if batch == 1:
    est = estimate_problem(problem, config, jax.random.key(0))
else:
    probs = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *jnp.shape(x))), problem)
    fn = jax.jit(jax.vmap(lambda pb, k: estimate_problem(pb, config, k)))
    est = fn(probs, jax.random.split(jax.random.key(0), batch))
jax.block_until_ready(est.params)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"batch": batch, "baseline_mib": base / 1024, "peak_mib": peak / 1024}))
"""


def main():
    rows = []
    for batch in (1, 64):
        with tempfile.TemporaryDirectory() as cache:
            for run in ("compiling", "warm cache"):
                rows.append({"run": run, **run_child(CHILD, str(batch), cache)})
                print(rows[-1])
    write_json("memory.json", {"config": "default", "pair": "N5 previous → variant 2 (204 × 204)", "rows": rows})


if __name__ == "__main__":
    main()
