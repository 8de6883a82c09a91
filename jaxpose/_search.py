"""Global search (evosax CMA-ES) and local refine (optimistix) of a displacement p.

Both work in normalised coordinates y = p / scale. The global stage uses the search box
(scale = box half-widths, so the box is [−1, 1]⁶; candidates are clipped into it before
scoring) and maximises the configured objective, scoring each generation with one
[`score_batch`][] call inside `lax.scan`. The local stage uses scale = (1°, 1°, 1°, 1 cm,
1 cm, 1 cm), which makes the soft objective's Hessian well conditioned for BFGS.
evosax and optimistix minimise, so both see −f.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ._batch import score_batch
from ._config import Config
from ._neighbours import spread_subset
from ._objective import soft_score
from ._poses import PARAMETER_SCALE
from ._problem import Problem
from ._tree import tree_select

EDGE = 0.98
"""A global result whose largest coordinate is at least this fraction of the box half-width
from the box centre lies at the edge: the optimum may lie outside the box."""


class GlobalResult(eqx.Module):
    """Result of the global stage.

    - `params`: the best p found, radians and metres, frame n; `score`: its objective value.
    - `history`: the best objective value of each CMA-ES generation (of the first search).
    - `evaluations`: objective evaluations, all searches.
    - `at_edge`: the best point lies at the edge of the (last) box.
    - `recentred`: re-centred searches that ran (in the search that gave the best).
    - `restarts`: independent restarts that ran after the first search.
    """

    params: Float[Array, "6"]
    score: Float[Array, ""]
    history: Float[Array, " G"]
    evaluations: Int[Array, ""]
    at_edge: Bool[Array, ""]
    recentred: Int[Array, ""]
    restarts: Int[Array, ""]


def box_scale(config: Config) -> Float[Array, "6"]:
    return jnp.array([config.search.angle_box] * 3 + [config.search.shift_box] * 3)


def global_search(problem: Problem, config: Config, key: PRNGKeyArray, start=None) -> GlobalResult:
    """CMA-ES (evosax) over the search box centred on `start` (default p = 0), scoring
    `problem.search_problem` (the coarse problem where `GlobalSearch.coarse_factor` > 1)."""
    # Imported where the search is traced (half a second of importing flax and optax): a
    # process whose programs load from their files (`jaxpose._programs`) never needs it.
    from evosax.algorithms import CMA_ES

    scored = problem.search_problem
    dtype = problem.d.dtype
    scale = box_scale(config).astype(dtype)
    centre = jnp.zeros(6, dtype) if start is None else jnp.asarray(start, dtype)
    es = CMA_ES(population_size=config.search.population, solution=jnp.zeros(6, dtype))
    params = es.default_params.replace(std_init=jnp.asarray(0.3, dtype))
    key, k_init = jax.random.split(key)
    state = es.init(k_init, jnp.zeros(6, dtype), params)

    def to_p(y):
        return centre + jnp.clip(y, -1.0, 1.0) * scale

    def generation(carry, k):
        state = carry
        k_ask, k_tell = jax.random.split(k)
        # evosax broadcasts (6,) against (population, 6) inside ask/tell; our own code does not.
        with jax.numpy_rank_promotion("allow"):
            ys, state = es.ask(k_ask, state, params)
        f = score_batch(jax.vmap(to_p)(ys), scored, config.search.objective)
        with jax.numpy_rank_promotion("allow"):
            state, _ = es.tell(k_tell, ys, -f, state, params)
        return state, jnp.max(f)

    state, history = jax.lax.scan(generation, state, jax.random.split(key, config.search.generations))
    best = to_p(state.best_solution)
    at_edge = jnp.max(jnp.abs(jnp.clip(state.best_solution, -1.0, 1.0))) >= EDGE
    evaluations = jnp.asarray(config.search.population * config.search.generations, jnp.int32)
    zero = jnp.asarray(0, jnp.int32)
    return GlobalResult(best, -state.best_fitness, history, evaluations, at_edge, zero, zero)


def recentred_search(problem: Problem, config: Config, key: PRNGKeyArray) -> GlobalResult:
    """[`global_search`][] over the box, then up to `config.search.recentre` more searches, each over
    a box centred on the previous best, while that best lies at the edge of its box.

    A best point at the edge means the optimum may lie outside the box (a motion larger than
    the box, or a translation pushed out by a large rotation about a far axis); a search
    centred there reaches (1 + recentre) box half-widths from p = 0. A new search replaces
    the previous result only if it scores at least as well. `at_edge` of the result says
    whether the last search still ended at its edge.

    All searches are one `lax.while_loop` over a single traced CMA-ES, so the search compiles
    once whatever `recentre` is, and under `jax.vmap` a batch pays for as many searches as
    its neediest pair (not for all of them, as `lax.cond` turned into a select would).
    """
    dtype = problem.d.dtype

    def search(state):
        prev, round_ = state
        start = jnp.where(round_ == 0, jnp.zeros(6, dtype), prev.params)
        new = global_search(problem, config, jax.random.fold_in(key, round_), start=start)
        keep = new.score >= prev.score
        pick = lambda a, b: jnp.where(keep, a, b)  # noqa: E731
        result = GlobalResult(
            pick(new.params, prev.params),
            pick(new.score, prev.score),
            jnp.where(round_ == 0, new.history, prev.history),  # the first search's history
            prev.evaluations + new.evaluations,
            pick(new.at_edge, prev.at_edge),
            round_,
            prev.restarts,
        )
        return result, round_ + 1

    def more(state):
        result, round_ = state
        return (round_ == 0) | (result.at_edge & (round_ <= config.search.recentre))

    empty = GlobalResult(
        jnp.zeros(6, dtype),
        jnp.asarray(-jnp.inf, dtype),
        jnp.zeros(config.search.generations, dtype),
        jnp.asarray(0, jnp.int32),
        jnp.asarray(True),
        jnp.asarray(0, jnp.int32),
        jnp.asarray(0, jnp.int32),
    )
    result, _ = jax.lax.while_loop(more, search, (empty, jnp.asarray(0, jnp.int32)))
    return result


def restarted_search(problem: Problem, config: Config, key: PRNGKeyArray) -> GlobalResult:
    """[`recentred_search`][], then up to `config.search.restarts` independent ones (new keys,
    `jax.random.fold_in(key, r)`, r = 1, 2, …) while the best score is below
    `config.search.restart_below`; the best-scoring search is the result.

    Why: over a ±90° box CMA-ES sometimes settles in a wrong basin (a ≈90° turn that lines
    up the target's flat faces) whose score is lower than the truth's; another search from
    a new key often finds the truth's basin. A score at or above `restart_below` is trusted
    and stops the restarts, so pairs that match well pay for one search. With
    `restarts = 0` this is `recentred_search` with `key`, unchanged.

    evosax's restart controllers restart *within* a scan on CMA-ES stagnation and keep a
    fixed generation budget; here the unit restarted is the whole re-centred search and the
    stopping rule is the score, hence a `lax.while_loop` of our own. Under `jax.vmap` a
    batch pays for as many restarts as its neediest pair.
    """
    first = recentred_search(problem, config, key)
    if config.search.restarts == 0:
        return first

    def search(state):
        best, round_ = state
        new = recentred_search(problem, config, jax.random.fold_in(key, round_))
        chosen = tree_select(new.score > best.score, new, best)
        total = best.evaluations + new.evaluations
        return eqx.tree_at(lambda r: (r.evaluations, r.restarts), chosen, (total, round_)), round_ + 1

    def more(state):
        best, round_ = state
        return (best.score < config.search.restart_below) & (round_ <= config.search.restarts)

    best, _ = jax.lax.while_loop(more, search, (first, jnp.asarray(1, jnp.int32)))
    return best


class LocalResult(eqx.Module):
    """Result of the local refine: `params` (frame n, radians and metres), the soft objective
    `score` there, whether the minimiser `converged`, and its `steps`."""

    params: Float[Array, "6"]
    score: Float[Array, ""]
    converged: Bool[Array, ""]
    steps: Int[Array, ""]


def thinned_current(problem: Problem, points: int | None) -> Problem:
    """`problem` with its current points thinned evenly to at most `points` (None, or no more
    than that: unchanged). The previous side, built from the previous cloud, stays."""
    if points is None or points >= problem.curr.shape[1]:
        return problem
    idx, live = spread_subset(problem.curr_valid, points)
    return eqx.tree_at(
        lambda p: (p.curr, p.curr_valid), problem, (problem.curr[:, idx], live & problem.curr_valid[idx])
    )


def local_refine(problem: Problem, config: Config, start: Float[Array, "6"]) -> LocalResult:
    """Maximise the soft objective from `start` with the config's optimistix minimiser
    (`Config.refine`), in coordinates of 1° and 1 cm, on the current points thinned to
    `Refine.points`; no refine returns `start`. The result is kept only if it scores at least
    as well as `start` on all the current points."""
    dtype = problem.d.dtype
    start = jnp.asarray(start, dtype)
    if config.refine is None:
        return LocalResult(start, soft_score(start, problem), jnp.asarray(True), jnp.asarray(0, jnp.int32))
    scale = jnp.asarray(PARAMETER_SCALE, dtype)

    def loss(y, pb):
        return -soft_score(y * scale, pb)

    scored = thinned_current(problem, config.refine.points)
    sol = optx.minimise(
        loss, config.refine.solver, start / scale, scored, max_steps=config.refine.max_steps, throw=False
    )
    p = sol.value * scale
    # Both points in one batch: one traced copy of the objective in the program instead of two
    # (about 0.6 s less to compile on the 2-core CPU; docs, Performance).
    f, f0 = score_batch(jnp.stack([p, start]), problem, "soft")
    better = jnp.isfinite(f) & (f >= f0)  # never return a worse point than the start
    return LocalResult(
        jnp.where(better, p, start),
        jnp.where(better, f, f0),
        sol.result == optx.RESULTS.successful,
        jnp.asarray(sol.stats["num_steps"], jnp.int32),
    )
