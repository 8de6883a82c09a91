"""Simulator speed: compile time and median time per 204 × 204 frame, single and vmapped.

uv run python experiments/bench_simulator.py  →  results/bench_simulator.json
"""

import jax
import jax.numpy as jnp
from _common import T_PAPER, paper_rotation, time_call, write_json

import jaxpose as jp


def main(batch: int = 16, repeats: int = 30):
    camera = jp.Camera.camcube2()
    out = {}
    for shape in ("n1", "n5"):
        target = getattr(jp.targets, shape)()
        single = jax.jit(jp.simulate)
        R = paper_rotation("previous")
        res = time_call(single, camera, target, R, T_PAPER, repeats=repeats)
        Rs = jnp.stack([jp.rotation(0.01 * i, 0.4, 0.0) for i in range(batch)])
        ts = jnp.broadcast_to(T_PAPER, (batch, 3))
        batched = jax.jit(jax.vmap(jp.simulate, (None, None, 0, 0)))
        resb = time_call(batched, camera, target, Rs, ts, repeats=repeats)
        out[shape] = {
            "single": {**res, "ms_per_frame": res["median_s"] * 1e3},
            f"vmap_{batch}": {**resb, "ms_per_frame": resb["median_s"] / batch * 1e3},
        }
        print(
            shape,
            f"single {res['median_s'] * 1e3:.2f} ms/frame (compile {res['compile_s']:.2f} s);",
            f"vmap {batch}: {resb['median_s'] / batch * 1e3:.2f} ms/frame (compile {resb['compile_s']:.2f} s)",
        )
    write_json("bench_simulator.json", {"pixels": camera.num_pixels, "results": out})


if __name__ == "__main__":
    main()
