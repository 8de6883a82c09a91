"""`estimate`: the displacement between two clouds, end to end, with a status.

Problem → global search (CMA-ES) → local refine (soft objective) → fine stage (point-to-plane
least squares on the near-plane points, `jaxpose.fine`) → hard score reported.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ._checks import is_concrete
from ._programs import BoundedJit
from .cloud import Cloud
from .config import Config
from .fine import fine_refine
from .frame import PlaneFrame
from .objective import hard_score, soft_score
from .poses import motion_from_displacement
from .problem import Problem, _build, check_range, grow_capacities, raise_for_codes, sized_config
from .search import box_scale, local_refine, restarted_search

SUCCESS, NOT_CONVERGED, LOW_SCORE, DEGENERATE, NON_FINITE, AT_BOX_EDGE = 0, 1, 2, 3, 4, 5
STATUS_TEXT = {
    SUCCESS: "success",
    NOT_CONVERGED: "the local refine or the fine stage did not converge",
    LOW_SCORE: "the best hard score is below Config.min_score: the patterns do not match",
    DEGENERATE: "the problem is unusable (see Problem.status: frame, capacities, too few points)",
    NON_FINITE: "a non-finite value appeared",
    AT_BOX_EDGE: "the global search ended at the edge of its box (after Config.recentre re-centred searches): "
    "the motion may lie outside it; widen the box (Config.wide()) or give a prior",
}
STATUS_NAME = {
    SUCCESS: "success",
    NOT_CONVERGED: "not converged",
    LOW_SCORE: "low score",
    DEGENERATE: "degenerate",
    NON_FINITE: "non-finite",
    AT_BOX_EDGE: "at box edge",
}
"""Short names of the status codes, for tables."""


class Estimate(eqx.Module):
    """Result of [`estimate`][].

    **Fields:**

    - `params`: p = (θ, φ, ψ, x, y, z), radians and metres, frame ν relative to frame n.
    - `rotation`, `translation`: the target motion in the camera frame, x ↦ R x + t, so
      estimates can be chained.
    - `frame`: the plane frame n of the previous cloud.
    - `hard`, `soft`: the objectives at `params`.
    - `status`: one of `SUCCESS` … `AT_BOX_EDGE` (`STATUS_TEXT`); `success` is status == 0.
    - `evaluations`: objective evaluations of the global stage; `local_steps`: refine steps;
      `fine_steps`: Levenberg–Marquardt steps of the fine stage, all rounds (0 without one).
    - `history`: best objective value of each CMA-ES generation (of the first centred search
      of the restart that gave the result).
    - `recentred`: re-centred CMA-ES searches that ran (see `Config.recentre`) in the search
      that gave the result; `restarts`: independent searches after the first
      (`Config.restarts`).
    - `global_params`, `global_score`: the global stage's result, before the refine.
    - `inliers`, `fine_rms`: the fine stage's inlier fraction and inlier RMS point-to-plane
      residual (metres) at its result; NaN when `Config.fine` is "none".
    - `fine_kept`: whether `params` is the fine stage's result (False: no fine stage, or its
      hard score fell more than `Config.fine_guard` below the refine's, which then stands).
    """

    params: Float[Array, "6"]
    rotation: Float[Array, "3 3"]
    translation: Float[Array, "3"]
    frame: PlaneFrame
    hard: Float[Array, ""]
    soft: Float[Array, ""]
    status: Int[Array, ""]
    evaluations: Int[Array, ""]
    local_steps: Int[Array, ""]
    fine_steps: Int[Array, ""]
    history: Float[Array, " G"]
    recentred: Int[Array, ""]
    restarts: Int[Array, ""]
    global_params: Float[Array, "6"]
    global_score: Float[Array, ""]
    inliers: Float[Array, ""]
    fine_rms: Float[Array, ""]
    fine_kept: Bool[Array, ""]

    @property
    def success(self) -> Bool[Array, ""]:
        return self.status == SUCCESS


FINE_TIE = 0.01
"""Inlier fractions closer than this count as equal when two fine-stage results are compared."""


def better_fine(a, b):
    """The fine-stage result that explains more of the current cloud: the larger inlier
    fraction, or, within `FINE_TIE`, the smaller weighted RMS residual."""
    pick_b = (b.inliers > a.inliers + FINE_TIE) | ((b.inliers >= a.inliers - FINE_TIE) & (b.rms < a.rms))
    return jax.tree.map(lambda x, y: jnp.where(pick_b, y, x), a, b)


def within_reach(p: Float[Array, "6"], config: Config) -> Bool[Array, ""]:
    """Whether p (frame n, radians and metres) lies where the search can reach: within
    (1 + `recentre`) box half-widths of p = 0. The fine stage's result is dropped outside it, so
    that a slide along a free direction never carries the estimate out of the box."""
    return jnp.all(jnp.abs(p) <= (1 + config.recentre) * box_scale(config).astype(p.dtype))


@eqx.filter_jit
def estimate_problem(problem: Problem, config: Config, key: PRNGKeyArray) -> Estimate:
    """[`estimate`][] on a prepared [`jaxpose.Problem`][] (pure, jitted, vmappable)."""
    glob = restarted_search(problem, config, key)
    loc = local_refine(problem, config, glob.params)
    p, converged = loc.params, loc.converged
    inliers = rms = jnp.asarray(jnp.nan, problem.d.dtype)
    hard = hard_score(p, problem)
    fine_kept = jnp.asarray(False)
    fine_steps = jnp.asarray(0, jnp.int32)
    if config.fine != "none":
        fine = fine_refine(problem, config, loc.params)
        if config.fine_from_rest:
            fine = better_fine(fine, fine_refine(problem, config, jnp.zeros_like(loc.params)))
        # The fine stage fits surfaces, not patterns: where the visible faces leave a direction
        # free it can slide along it (24 cm on a noise-free view with 1024 points a side, in a
        # development run of experiments/bench_estimate.py). Its result is kept unless the method's reference
        # score drops by more than `fine_guard`; then the refine's result stands.
        fine_hard = hard_score(fine.params, problem)
        fine_kept = (fine_hard >= hard - config.fine_guard) & within_reach(fine.params, config)
        # When kept, the fine stage's convergence is the one that counts (BFGS on the soft
        # objective may stop on a kink short of its tolerance and not matter).
        p = jnp.where(fine_kept, fine.params, p)
        converged = jnp.where(fine_kept, fine.converged, converged)
        hard = jnp.where(fine_kept, fine_hard, hard)
        inliers, rms, fine_steps = fine.inliers, fine.rms, fine.steps
    finite = jnp.all(jnp.isfinite(p)) & jnp.isfinite(hard)
    # First matching condition wins: the order is the priority of the statuses.
    status = jnp.select(
        [problem.status != 0, ~finite, hard < config.min_score, glob.at_edge, ~converged],
        [DEGENERATE, NON_FINITE, LOW_SCORE, AT_BOX_EDGE, NOT_CONVERGED],
        SUCCESS,
    )
    p = jnp.where(finite, p, jnp.zeros_like(p))
    R, t = motion_from_displacement(problem.frame.origin, problem.frame.axes, p)
    return Estimate(
        params=p,
        rotation=R,
        translation=t,
        frame=problem.frame,
        hard=jnp.where(finite, hard, 0.0),
        soft=soft_score(p, problem),
        status=jnp.asarray(status, jnp.int32),
        evaluations=jnp.asarray(glob.evaluations, jnp.int32),
        local_steps=jnp.asarray(loc.steps, jnp.int32),
        fine_steps=fine_steps,
        history=glob.history,
        recentred=jnp.asarray(glob.recentred, jnp.int32),
        restarts=jnp.asarray(glob.restarts, jnp.int32),
        global_params=glob.params,
        global_score=glob.score,
        inliers=inliers,
        fine_rms=rms,
        fine_kept=fine_kept,
    )


def estimate(prev: Cloud, curr: Cloud, config: Config | None = None, *, key: PRNGKeyArray) -> Estimate:
    """Displacement of the target between the previous and the current cloud.

    **Arguments:**

    - `prev`, `curr`: the two [`jaxpose.Cloud`][]s, camera frame, metres.
    - `config`: a [`jaxpose.Config`][] (default `Config.accurate()`).
    - `key`: PRNG key of the global search; the same key gives the same result.

    **Returns:**

    An [`Estimate`][]. Pure; works under `jax.jit` and `jax.vmap` over pairs and keys. At the
    Python boundary an unusable pair raises ValueError (see `Problem.build`); under jit it
    comes back with status `DEGENERATE` and never as a success.
    """
    config = Config.accurate() if config is None else config
    if not is_concrete(prev, curr):
        return estimate_problem(Problem.build(prev, curr, config), config, key)
    prev.check("previous cloud")
    curr.check("current cloud")
    check_range(prev, curr, config)
    config = sized_config(prev, curr, config)
    for _ in range(GROW_TRIES):
        est, status, frame_status = _estimate_pair(prev, curr, config, key)
        grown = grow_capacities(config, int(status))
        if grown is None:
            break
        config = grown
    raise_for_codes(int(status), int(frame_status))
    return est


GROW_TRIES = 4
"""Compiled calls `estimate` may make at the Python boundary: a capacity that the sizing
missed (a rounding at the coarse level) is grown and the pair run again."""


def _build_and_estimate(prev: Cloud, curr: Cloud, config: Config, key: PRNGKeyArray):
    problem = _build(prev, curr, config)
    return estimate_problem(problem, config, key), problem.status, problem.frame.status


_estimate_pair = BoundedJit(_build_and_estimate)
"""Build, search, refine and fine stage as one compiled program per capacity bucket (the most
recently used ones kept in memory, see `jaxpose._programs`)."""


__all__ = ["STATUS_NAME", "STATUS_TEXT", "Estimate", "estimate", "estimate_problem"]
