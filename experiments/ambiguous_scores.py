"""Would the pattern objectives break the fine stage's ties? For every estimate flagged
`ambiguous` on the realistic benchmark's pairs, the rotation errors of its two hypotheses (the
estimate and the runner-up, `Estimate.alternative`) and the hard and soft objectives at each;
then how many ambiguous pairs each rule would find (< 1°): the estimate as it is, the
hypothesis of higher hard score, of higher soft score.

One compiled build-and-estimate for all pairs (capacities sized for the largest), so the
estimates can differ from the public call's in float32 rounding. Printed, not committed.

    uv run python experiments/ambiguous_scores.py [levels, default 0.5,1,2] [pairs per target, 8] [seed, 0]
"""

from __future__ import annotations

import sys

import equinox as eqx
import jax
import jax.numpy as jnp

import jaxpose as jp
from jaxpose._estimate import estimate_problem
from jaxpose._poses import motion_from_displacement
from jaxpose._problem import _build, sized_batch_config
from jaxpose.evaluation import realistic


@eqx.filter_jit
def estimate_with_scores(prev, curr, config, key):
    """The estimate, and for (estimate, runner-up): hard and soft objectives and camera-frame motions."""
    problem = _build(prev, curr, config)
    est = estimate_problem(problem, config, key)
    ps = jnp.stack([est.params, est.alternative])
    hard = jax.vmap(jp.hard_score, (0, None))(ps, problem)
    soft = jax.vmap(jp.soft_score, (0, None))(ps, problem)
    rotations, translations = jax.vmap(lambda p: motion_from_displacement(problem.frame.origin, problem.frame.axes, p))(
        ps
    )
    return est, hard, soft, rotations, translations


def main(levels=(0.5, 1.0, 2.0), pairs: int = 8, seed: int = 0) -> None:
    cases = realistic.make_cases(pairs=pairs, levels=levels, seed=seed)
    config = sized_batch_config([(c.prev, c.curr) for c in cases], jp.Config())
    found = {"as is": 0, "higher hard score": 0, "higher soft score": 0}
    flagged = 0
    for i, case in enumerate(cases):
        est, hard, soft, rotations, translations = estimate_with_scores(
            case.prev, case.curr, config, jax.random.fold_in(jax.random.key(0), i)
        )
        if not bool(est.ambiguous):
            continue
        flagged += 1
        rot = [realistic.errors(case, rotations[k], translations[k])["rotation_error_deg"] for k in range(2)]
        print(
            f"{case.label:22s} rotation error {rot[0]:7.3f}° / {rot[1]:7.3f}°  hard {float(hard[0]):.4f} / "
            f"{float(hard[1]):.4f}  soft {float(soft[0]):.4f} / {float(soft[1]):.4f}",
            flush=True,
        )
        for rule, k in (
            ("as is", 0),
            ("higher hard score", int(hard[1] > hard[0])),
            ("higher soft score", int(soft[1] > soft[0])),
        ):
            found[rule] += rot[k] < 1.0
    print(f"{len(cases)} pairs, {flagged} ambiguous; found among them by rule: {found}")


if __name__ == "__main__":
    args = sys.argv[1:]
    levels = tuple(float(x) for x in args[0].split(",")) if args else (0.5, 1.0, 2.0)
    main(levels, int(args[1]) if len(args) > 1 else 8, int(args[2]) if len(args) > 2 else 0)
