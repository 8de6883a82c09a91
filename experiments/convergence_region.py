"""Convergence region of the local stage (issue 7, the Nelder–Mead paper's claim).

From the truth of a pair plus an offset of size δ in a random direction (normalised units of
1° and 1 cm, so δ = 4 moves each coordinate by about 4/√6 ° or cm), each method refines the
soft objective; a run succeeds when it ends < 1° (rotation angle) and < 1 cm from the truth.
Methods: optimistix BFGS (quasi-Newton), optimistix NelderMead, and evosax CMA-ES (the
default global stage, its ±20° / ±0.10 m box centred on the offset start). The widening
factor is the largest δ at which a method still succeeds in ≥ 90 % of the runs, relative
to BFGS (the Nelder–Mead paper claims 10× over Newton for its orbit problem).

    uv run python experiments/convergence_region.py  →  results/convergence_region.json
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import write_json

import jaxpose as jp
from jaxpose._poses import PARAMETER_SCALE
from jaxpose._search import global_search, local_refine
from jaxpose.sim import paper_pairs

OFFSETS = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
TRIALS = 6
METHODS = {
    "BFGS": jp.Config.thorough(max_points=5120, local="bfgs", local_steps=200),
    "NelderMead": jp.Config.thorough(max_points=5120, local="nelder_mead", local_steps=600),
    "CMA-ES": jp.Config.thorough(max_points=5120, local="none"),
}


@jax.jit
def _errors(p, truth):
    """Rotation angle (°) and translation distance (cm) between two displacements in frame n."""
    angle = jp.rotation_angle(jp.rotation(p[0], p[1], p[2]), jp.rotation(truth[0], truth[1], truth[2]))
    return jnp.degrees(angle), 100 * jnp.linalg.norm(p[3:] - truth[3:])


@eqx.filter_jit
def run_method(name, config, problem, start, key):
    if name == "CMA-ES":
        return global_search(problem, config, key, start=start).params
    return local_refine(problem, config, start).params


def main():
    rows = []
    scale = np.asarray(PARAMETER_SCALE)
    for pair in paper_pairs():
        problem = jp.Problem.build(pair.prev, pair.curr, METHODS["BFGS"])
        truth = jp.true_displacement(problem.frame, pair.R1, pair.t1, pair.R2, pair.t2)
        rng = np.random.default_rng(0)
        for delta in OFFSETS:
            for trial in range(TRIALS):
                direction = rng.normal(size=6)
                start = truth + delta * direction / np.linalg.norm(direction) * scale
                for name, config in METHODS.items():
                    p = run_method(name, config, problem, start, jax.random.key(trial))
                    angle, shift = (float(x) for x in _errors(p, truth))
                    rows.append(
                        {"pair": pair.label, "delta": delta, "trial": trial, "method": name,
                         "rotation_error_deg": angle, "translation_error_cm": shift,
                         "success": angle < 1.0 and shift < 1.0}
                    )  # fmt: skip
            rates = {
                m: np.mean([r["success"] for r in rows if r["pair"] == pair.label and r["delta"] == delta
                            and r["method"] == m])
                for m in METHODS
            }  # fmt: skip
            print(pair.label, f"δ = {delta:5.1f}", {m: f"{v:.0%}" for m, v in rates.items()}, flush=True)
    table = {
        m: {
            str(d): float(np.mean([r["success"] for r in rows if r["delta"] == d and r["method"] == m]))
            for d in OFFSETS
        }
        for m in METHODS
    }
    reach = {m: max([d for d in OFFSETS if table[m][str(d)] >= 0.9], default=0.0) for m in METHODS}
    widening = {m: (reach[m] / reach["BFGS"] if reach["BFGS"] else None) for m in METHODS}
    print("success rate by δ:", table)
    print("largest δ with ≥ 90 %:", reach, "widening vs BFGS:", widening)
    write_json(
        "convergence_region.json",
        {"offsets": OFFSETS, "trials_per_pair": TRIALS, "success_rate": table, "reach": reach,
         "widening_vs_bfgs": widening, "rows": rows},
    )  # fmt: skip


if __name__ == "__main__":
    main()
