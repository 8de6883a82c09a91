"""estimate: recovery, determinism, batching and honest failure (fast config, one compile)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from conftest import PAPER_CAPACITIES, T_PAPER, paper_rotation

import jaxpose as jp
from jaxpose._estimate import (
    AT_BOX_EDGE,
    DEGENERATE,
    LOW_SCORE,
    NOT_CONVERGED,
    STATUS_TEXT,
    SUCCESS,
    UNCERTAIN,
    estimate_problem,
    is_uncertain,
)
from jaxpose._search import recentred_search, restarted_search

CONFIG = jp.Config.fast(capacities=PAPER_CAPACITIES)  # fixed capacities: the tests share one compile


def errors(est, variant):
    truth = jp.true_displacement(est.frame, paper_rotation("previous"), T_PAPER, paper_rotation(variant), T_PAPER)
    rot = float(jp.rotation_angle(jp.rotation(*est.params[:3]), jp.rotation(*truth[:3])))
    return np.degrees(rot), 100 * float(jnp.linalg.norm(est.params[3:] - truth[3:]))


@pytest.fixture(scope="module")
def n5_estimate(paper_clouds):
    return jp.estimate(paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"], CONFIG, key=jax.random.key(0))


def test_float32_clouds_run_in_the_sessions_precision(paper_clouds):
    """Under `jax_enable_x64` (the tests' setting) float32 clouds go through the Python boundary
    as float64 (`Cloud.floating`) and give the float64 program's estimate."""
    prev, curr = paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"]
    single = [jp.Cloud(jnp.asarray(c.points, jnp.float32), c.valid) for c in (prev, curr)]
    est = jp.estimate(*single, CONFIG, key=jax.random.key(0))
    assert est.params.dtype == jnp.float64
    assert int(est.status) == SUCCESS, STATUS_TEXT[int(est.status)]
    angle_deg, shift_cm = component_errors(est, "variant2")
    assert angle_deg <= 0.001 and shift_cm <= 0.001, (angle_deg, shift_cm)


def component_errors(est, variant):
    """Largest angle error (°) and translation-component error (cm) in frame n, as issue 4."""
    truth = jp.true_displacement(est.frame, paper_rotation("previous"), T_PAPER, paper_rotation(variant), T_PAPER)
    err = np.abs(np.asarray(est.params - truth))
    return np.degrees(err[:3]).max(), 100 * err[3:].max()


@pytest.mark.parametrize("shape", ["n1", "n5"])
@pytest.mark.parametrize("variant", ["variant1", "variant2"])
def test_paper_pairs_within_issue_bounds(paper_clouds, shape, variant):
    """Issue 4: every angle error ≤ 0.05° and every translation error ≤ 0.05 cm on the paper's
    four noise-free pairs (the paper: up to 1.17° and 0.36 cm; variant 1 failed)."""
    est = jp.estimate(paper_clouds[shape, "previous"], paper_clouds[shape, variant], CONFIG, key=jax.random.key(0))
    assert int(est.status) == SUCCESS, STATUS_TEXT[int(est.status)]
    angle_deg, shift_cm = component_errors(est, variant)
    assert angle_deg <= 0.05 and shift_cm <= 0.05, (angle_deg, shift_cm)
    assert angle_deg <= 0.001 and shift_cm <= 0.001, (angle_deg, shift_cm)  # measured: < 5e-5° in float32
    # Noise-free: an exact fit. `inliers` is the share of current points within 3 cm of a planar
    # previous point: 0.65–0.85 with the default's 896 points a side (0.75+ with 2048). The
    # Cauchy-weighted RMS keeps the down-weighted edge matches (a current point near a panel's
    # edge matched to the other face's plane, centimetres off at weight ≈ 1e-3): 2–3e-5 m.
    assert float(est.fine.inliers) > 0.65 and float(est.fine.rms) < 1e-4 and bool(est.fine_kept)
    assert 0 < int(est.stats["fine_steps"]) <= CONFIG.fine.rounds * CONFIG.fine.steps


def test_recovers_the_paper_variant2_displacement(n5_estimate):
    est = n5_estimate
    assert int(est.status) in (SUCCESS, NOT_CONVERGED)
    rot_deg, trans_cm = errors(est, "variant2")
    assert rot_deg < 0.05 and trans_cm < 0.05, (rot_deg, trans_cm)
    assert float(est.hard) > 0.85
    # Camera-frame motion consistent with the displacement in frame n.
    R_true = paper_rotation("variant2") @ paper_rotation("previous").T
    assert np.degrees(float(jp.rotation_angle(est.rotation, R_true))) < 0.5
    # CMA-ES history is recorded; the fine stage (a different objective) may trade a little
    # soft score for accuracy, but not the match itself.
    assert est.search.history.shape == (CONFIG.search.generations,)
    assert float(est.soft) >= float(est.search.score) - 0.05


def test_same_key_gives_identical_result(paper_clouds, n5_estimate):
    again = jp.estimate(paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"], CONFIG, key=jax.random.key(0))
    for a, b in zip(jax.tree.leaves(n5_estimate), jax.tree.leaves(again), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_vmap_over_pairs_equals_a_loop(paper_clouds):
    """`jax.vmap` of `estimate` over two pairs gives what a loop of public calls gives. The
    public call's program is compiled with jaxpose's XLA options (`_programs.compiler_options`)
    and the vmapped one with the caller's, so they agree to round-off, not bit for bit."""
    prevs = jax.tree.map(lambda *x: jnp.stack(x), *[paper_clouds["n5", "previous"]] * 2)
    currs = jax.tree.map(lambda *x: jnp.stack(x), paper_clouds["n5", "variant1"], paper_clouds["n5", "variant2"])
    keys = jax.random.split(jax.random.key(5), 2)
    batch = jax.vmap(lambda a, b, k: jp.estimate(a, b, CONFIG, key=k))(prevs, currs, keys)
    for i, variant in enumerate(("variant1", "variant2")):
        prev, curr = paper_clouds["n5", "previous"], paper_clouds["n5", variant]
        public = jp.estimate(prev, curr, CONFIG, key=keys[i])
        np.testing.assert_allclose(np.asarray(batch.params[i]), np.asarray(public.params), atol=1e-5)
        assert int(batch.status[i]) == int(public.status) == SUCCESS
        assert int(batch.search.evaluations[i]) == int(public.search.evaluations)


def test_a_different_target_is_not_reported_as_success(camera, paper_clouds):
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    sphere = jp.simulate(camera, jp.targets.Mesh.create(m.vertices, m.faces), paper_rotation("previous"), T_PAPER)
    est = jp.estimate(paper_clouds["n5", "previous"], sphere, CONFIG, key=jax.random.key(0))
    assert int(est.status) == LOW_SCORE and not bool(est.success)


def test_degenerate_pair_under_jit_is_flagged_not_success(paper_clouds):
    # A collinear cloud (a coplanar one has a frame: `test_objective.py`).
    flat = jp.Cloud.from_points(np.outer(np.random.default_rng(0).normal(size=5120), [1.0, 2.0, 0.5]) + [0, 0, 4])
    # Under jit nothing can raise: the problem is built there (as `estimate` does under a
    # tracer), then the compiled `estimate_problem` runs on it. The paper's preset (no refine,
    # no fine stage) keeps the compile short: the status comes from the frame, whatever the
    # stages.
    config = jp.Config.paper(capacities=PAPER_CAPACITIES)
    problem = jax.jit(lambda a, b: jp.Problem.build(a, b, config))(flat, flat)
    assert int(problem.frame.status) == 2
    est = estimate_problem(problem, config, jax.random.key(0))
    assert int(est.status) == DEGENERATE and not bool(est.success)
    assert np.all(np.isfinite(np.asarray(est.params)))


def test_degenerate_pair_raises_at_the_boundary_before_its_program_compiles(paper_clouds):
    from jaxpose._estimate import _estimate_pair

    _estimate_pair.clear()
    flat = jp.Cloud.from_points(np.outer(np.random.default_rng(0).normal(size=50), [1.0, 2.0, 0.5]) + [0, 0, 4])
    with pytest.raises(ValueError, match="previous cloud: the points are collinear"):
        jp.estimate(flat, paper_clouds["n5", "variant2"], CONFIG, key=jax.random.key(0))
    few = jp.Cloud.from_points(np.asarray(paper_clouds["n5", "variant2"].compact())[:9])
    with pytest.raises(ValueError, match="current cloud: fewer than 10"):
        jp.estimate(paper_clouds["n5", "previous"], few, CONFIG, key=jax.random.key(0))
    assert not _estimate_pair.programs


def search_config(**search) -> jp.Config:
    """`Config.fast()` with these global-search settings."""
    return jp.Config.fast(search=jp.GlobalSearch(**search))


def test_the_search_scores_a_coarse_problem_of_the_same_frame(paper_clouds):
    """GlobalSearch.coarse_factor: the search's problem has cells (and slabs) of coarse_factor·d,
    at most coarse_points current points, the previous cloud's frame n, and no fine stage."""
    prev, curr = paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"]
    problem = jp.Problem.build(prev, curr, CONFIG)
    coarse = problem.search_problem
    assert coarse is problem.coarse and CONFIG.search.coarse_factor == 3
    assert float(coarse.d) == pytest.approx(3 * float(problem.d))
    assert coarse.curr.shape[1] == CONFIG.search.coarse_points == int(coarse.curr_valid.sum())
    np.testing.assert_array_equal(np.asarray(coarse.frame.axes), np.asarray(problem.frame.axes))
    assert coarse.coarse is None and int(coarse.fine.valid.sum()) == 0
    # A grid of ⌈C/3⌉ + 2 cells holds its patterns (cells three times as wide).
    assert coarse.grid_cells == -(-problem.grid_cells // 3) + 2 and int(coarse.status) == 0
    assert (
        jp.Problem.build(
            prev, curr, jp.Config.fast(search=jp.GlobalSearch(coarse_factor=1), capacities=CONFIG.capacities)
        ).search_problem.coarse
        is None
    )


def test_the_refine_scores_an_even_subset_of_the_current_points(n5_problem):
    """Refine.points: the refine's problem keeps the previous side and at most that many of the
    current points, all of them real current points; at or above the count it is the problem."""
    from jaxpose._search import thinned_current

    count = int(n5_problem.curr_valid.sum())
    thin = thinned_current(n5_problem, 1000)
    kept = np.asarray(thin.curr)[:, np.asarray(thin.curr_valid)].T
    everything = {tuple(x) for x in np.asarray(n5_problem.curr)[:, np.asarray(n5_problem.curr_valid)].T}
    assert count > 1000 and len(kept) == 1000 and all(tuple(x) in everything for x in kept)
    np.testing.assert_array_equal(np.asarray(thin.r_field), np.asarray(n5_problem.r_field))
    np.testing.assert_array_equal(np.asarray(thin.fine.normals), np.asarray(n5_problem.fine.normals))
    assert thinned_current(n5_problem, None) is n5_problem
    assert thinned_current(n5_problem, n5_problem.curr.shape[1]) is n5_problem
    with pytest.raises(ValueError, match="Refine.points"):
        jp.Refine(points=5)


def test_recentred_search_reaches_beyond_the_box_and_flags_its_edge(paper_clouds):
    # The N5 variant-2 truth has an angle of about 11.7° in frame n: outside a ±8° box. On the
    # full patterns (coarse=1): the default's coarse ones (cells three times as wide) resolve
    # the optimum more coarsely, which the refine then corrects.
    full = jp.Config.fast(search=jp.GlobalSearch(coarse_factor=1), capacities=CONFIG.capacities)
    problem = jp.Problem.build(paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"], full)
    truth = jp.true_displacement(
        problem.frame, paper_rotation("previous"), T_PAPER, paper_rotation("variant2"), T_PAPER
    )
    box = np.radians(8.0)
    assert np.abs(np.asarray(truth[:3])).max() > 1.2 * box
    one = recentred_search(problem, search_config(angle_box=box, recentre=0, coarse_factor=1), jax.random.key(1))
    assert bool(one.at_edge) and int(one.recentred) == 0
    more = recentred_search(problem, search_config(angle_box=box, recentre=2, coarse_factor=1), jax.random.key(1))
    assert int(more.recentred) >= 1 and not bool(more.at_edge)
    rot = np.degrees(float(jp.rotation_angle(jp.rotation(*more.params[:3]), jp.rotation(*truth[:3]))))
    assert rot < 1.0 and float(more.score) > float(one.score)


def test_restarts_keep_the_best_of_independent_searches_and_stop_on_a_trusted_score(n5_problem):
    key = jax.random.key(3)
    base = search_config(recentre=0)
    one, restarted = eqx.filter_jit(recentred_search), eqx.filter_jit(restarted_search)  # restart_below is traced
    first = one(n5_problem, base, key)
    # A score at or above restart_below is trusted: no restart, the first search unchanged.
    trusted = restarted(n5_problem, search_config(recentre=0, restarts=2, restart_below=0.0), key)
    assert int(trusted.restarts) == 0 and np.allclose(trusted.params, first.params, rtol=1e-9, atol=1e-12)
    # Never trusted: both restarts run, and the result is the best of the three searches,
    # checked against the searches run one by one with the documented keys.
    always = restarted(n5_problem, search_config(recentre=0, restarts=2, restart_below=1.0), key)
    searches = [first] + [one(n5_problem, base, jax.random.fold_in(key, r)) for r in (1, 2)]
    best = max(searches, key=lambda g: float(g.score))
    assert int(always.restarts) == 2
    assert int(always.evaluations) == sum(int(g.evaluations) for g in searches)
    assert np.isclose(float(always.score), float(best.score), rtol=1e-9)
    assert np.allclose(always.params, best.params, rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_wide_mode_captures_a_pair_that_three_planes_get_wrong():
    """Capture pair 71 (a 16° motion of N5 at a random attitude): three planes put their
    soft maximum 4° from the truth and the estimate reported a false success; wide mode's
    nine planes find it."""
    from jaxpose.sim import capture_pair

    pair = capture_pair(71)
    config = jp.Config.wide(capacities=jp.Capacities(max_points=10240, max_cells=1024, grid_cells=160))
    est = jp.estimate(pair.prev, pair.curr, config, key=jax.random.fold_in(jax.random.key(0), 71))
    R_true, _ = pair.motion
    assert int(est.status) == SUCCESS, STATUS_TEXT[int(est.status)]
    assert np.degrees(float(jp.rotation_angle(est.rotation, R_true))) < 0.1


@pytest.mark.slow  # an option off the default path (no recentring); its own compile. The default
# path's edge flag: test_recentred_search_reaches_beyond_the_box_and_flags_its_edge.
def test_a_motion_outside_the_box_is_not_reported_as_success(paper_clouds):
    config = jp.Config.fast(search=jp.GlobalSearch(angle_box=np.radians(8.0), recentre=0), capacities=PAPER_CAPACITIES)
    est = jp.estimate(paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"], config, key=jax.random.key(1))
    assert int(est.status) in (AT_BOX_EDGE, LOW_SCORE), STATUS_TEXT[int(est.status)]


def test_one_status_vocabulary(n5_estimate):
    """`Estimate.result` is a `Status` item; `status` is its code, and the code tables are
    views of the same enumeration."""
    est = n5_estimate
    assert jp.Status[est.result] == STATUS_TEXT[int(est.status)]
    assert bool(est.success) == (int(est.status) == SUCCESS) == bool(est.result == jp.Status.success)
    assert STATUS_TEXT[NOT_CONVERGED] == jp.Status[jp.Status.not_converged]
    assert STATUS_TEXT[AT_BOX_EDGE] == jp.Status[jp.Status.at_box_edge]
    assert STATUS_TEXT[UNCERTAIN] == jp.Status[jp.Status.uncertain]
    assert set(STATUS_TEXT) == set(range(8))
    assert not bool(est.ambiguous) and np.all(np.isfinite(np.asarray(est.alternative)))
    assert est.stats["evaluations"] == est.search.evaluations and est.stats["fine_steps"] == est.fine.steps


def test_the_covariance_of_an_exact_fit_is_tight_and_a_covariance(n5_estimate):
    """`Estimate.covariance` (camera frame, rad then m) of the noise-free paper pair: symmetric,
    positive definite, and far inside the uncertainty a success allows. The least squares'
    own rotation standard deviation (before the factor `covariance_factor`) is below 0.008°,
    and its residual scale (`Estimate.residual_scale`) is the floor's order, far below a
    millimetre."""
    from jaxpose._fine import SIGMA_FLOOR
    from jaxpose._uncertainty import covariance_factor

    cov = np.asarray(n5_estimate.covariance)
    assert cov.shape == (6, 6)
    np.testing.assert_allclose(cov, cov.T, atol=1e-15)
    assert np.linalg.eigvalsh(cov).min() > 0
    sigma = float(n5_estimate.residual_scale)
    assert SIGMA_FLOOR * (1 - 1e-6) <= sigma < 1e-3
    largest = np.linalg.eigvalsh(cov[:3, :3]).max()
    assert np.degrees(np.sqrt(largest / float(covariance_factor(CONFIG, sigma)))) < 0.008
    assert not bool(is_uncertain(n5_estimate.covariance, jp.Config()))


@pytest.mark.parametrize(
    "std_deg, threshold_deg, expected",
    [(0.1, 1 / 3, False), (0.5, 1 / 3, True), (0.5, np.inf, False), (np.nan, 1 / 3, True), (np.nan, np.inf, True)],
)
def test_a_success_needs_a_tight_covariance(std_deg, threshold_deg, expected):
    """`Status.uncertain`: the largest rotation standard deviation above
    `Thresholds.max_rotation_std_deg` (degrees), whatever its axis; a non-finite covariance
    is never a success."""
    axis = np.random.default_rng(3).normal(size=3)
    axis /= np.linalg.norm(axis)
    cov = np.eye(6) * 1e-10
    cov[:3, :3] += np.radians(std_deg) ** 2 * np.outer(axis, axis) if np.isfinite(std_deg) else np.nan
    config = jp.Config(thresholds=jp.Thresholds(max_rotation_std_deg=threshold_deg))
    assert bool(is_uncertain(jnp.asarray(cov), config)) == expected


def _fine_result(angles_deg, inliers, rms=0.003, conflict=np.nan):
    from jaxpose._fine import FineResult

    p = jnp.asarray([*np.radians(angles_deg), 0.0, 0.0, 0.0])
    return FineResult(
        p,
        jnp.asarray(True),
        jnp.asarray(5),
        jnp.asarray(inliers),
        jnp.asarray(rms),
        jnp.asarray(rms),
        jnp.asarray(900),
        jnp.asarray(conflict, jnp.float32),
        jnp.asarray(-1),
    )


@pytest.mark.parametrize(
    "b_angles, b_inliers, expected",
    [
        ((0.0, 0.0, 14.0), 0.675, True),  # a turn about a symmetry axis that fits as well
        ((0.0, 0.0, 14.0), 0.60, False),  # the first explains clearly more of the cloud
        ((0.3, 0.0, 0.5), 0.67, False),  # the same motion within 1°
        ((0.0, -1.2, 0.0), 0.67, True),
    ],
)
def test_two_equally_good_fits_far_apart_are_ambiguous(b_angles, b_inliers, expected):
    from jaxpose._estimate import equally_good_and_apart

    a = _fine_result((0.0, 0.0, 0.0), 0.67)
    b = _fine_result(b_angles, b_inliers)
    config = jp.Config()
    assert bool(equally_good_and_apart(a, b, config)) == expected
    assert bool(equally_good_and_apart(b, a, config)) == expected


def _stacked(*fits):
    return jax.tree.map(lambda *x: jnp.stack(x), *fits)


@pytest.mark.parametrize(
    "others, expected_deg",
    [
        ([((0.0, 0.8, 0.0), 0.672)], 0.8),  # an equally good fit 0.8° away
        ([((0.0, 0.8, 0.0), 0.69)], 0.0),  # 0.02 more: no tie (a fit the choice would have preferred)
        ([((0.0, 0.8, 0.0), 0.60)], 0.0),  # it explains clearly less
        ([((0.0, 0.8, 0.0), 0.0)], 0.0),  # an inactive run (no inliers)
        ([((0.3, 0.0, 0.0), 0.665), ((0.0, 0.0, 0.6), 0.675), ((5.0, 0.0, 0.0), 0.5)], 0.6),
    ],
)
def test_the_spread_is_the_largest_angle_to_an_equally_good_fit(others, expected_deg):
    """`fit_spread`: over the live runs whose inlier fractions lie within `FINE_TIE` of the
    chosen fit's, the largest rotation angle to it (radians); the chosen run itself adds 0."""
    from jaxpose._estimate import fit_spread

    chosen = _fine_result((0.0, 0.0, 0.0), 0.67)
    runs = _stacked(chosen, *(_fine_result(angles, inliers) for angles, inliers in others))
    spread = float(fit_spread(chosen, runs, 1 + len(others)))
    np.testing.assert_allclose(spread, np.radians(expected_deg), rtol=1e-4, atol=1e-9)


@pytest.mark.parametrize(
    "std_deg, spread_deg, expected",
    [(0.2, 0.0, False), (0.2, 0.4, False), (0.2, 0.6, True), (0.0, 0.7, True), (0.3, 0.3, True)],
)
def test_the_spread_of_equally_good_fits_counts_towards_uncertain(std_deg, spread_deg, expected):
    """`Status.uncertain` combines the covariance's largest rotation standard deviation with half
    the spread in quadrature: √(0.2² + 0.3²) = 0.36° > 1/3°, √(0.2² + 0.2²) = 0.28° is not."""
    cov = np.eye(6) * 1e-12
    cov[:3, :3] += np.radians(std_deg) ** 2 * np.diag([1.0, 0.0, 0.0])
    uncertain = is_uncertain(jnp.asarray(cov), jp.Config(), jnp.asarray(np.radians(spread_deg)))
    assert bool(uncertain) == expected


def test_the_paper_pair_has_no_spread(n5_estimate):
    """The noise-free paper pair: the fits from the search's best and from rest agree, so the
    status keeps its success on the covariance alone."""
    assert float(n5_estimate.spread) < np.radians(0.01)
    assert bool(n5_estimate.success)


def _frame_with_moments(moments):
    from jaxpose._frame import PlaneFrame

    return PlaneFrame(jnp.zeros(3), jnp.eye(3), jnp.asarray(moments), jnp.asarray(100), jnp.asarray(0))


@pytest.mark.parametrize(
    "moments, axis",
    [
        ((1.0, 0.92, 0.2), 2),  # elongated: the two largest moments close, it turns about axis 3
        ((1.0, 0.5, 0.45), 0),  # flat: the two smallest close, it turns about axis 1
        ((1.0, 0.7, 0.3), None),  # no two moments close: no turn
    ],
)
def test_symmetry_turns_about_the_axis_of_the_distinct_moment(moments, axis):
    from jaxpose._estimate import symmetry_turns

    config = jp.Config()
    turns = np.asarray(symmetry_turns(_frame_with_moments(moments), config))
    assert turns.shape == (2, 3)
    if axis is None:
        np.testing.assert_array_equal(turns, 0.0)
        return
    expected = np.zeros(3)
    expected[axis] = np.radians(config.fine.turn_deg)
    np.testing.assert_allclose(turns, np.stack([expected, -expected]), atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_a_turned_displacement_turns_the_moved_frame_about_its_own_origin(seed):
    """turned(p, v): G' = G exp(v), the translation kept; the moved frame's origin stays and a
    point on the turn axis of ν stays where p put it."""
    import jaxlie

    from jaxpose._estimate import turned

    rng = np.random.default_rng(seed)
    p = jnp.asarray([*rng.uniform(-0.5, 0.5, 3), *rng.uniform(-0.1, 0.1, 3)])
    v = jnp.asarray(rng.normal(size=3) * 0.3)
    q = turned(p, v)
    G = jp.rotation(*p[:3]) @ jaxlie.SO3.exp(v).as_matrix()
    np.testing.assert_allclose(np.asarray(jp.rotation(*q[:3])), np.asarray(G), atol=1e-10)
    np.testing.assert_array_equal(np.asarray(q[3:]), np.asarray(p[3:]))
    on_axis = 0.7 * v / jnp.linalg.norm(v)  # a point of frame ν on the turn's axis
    np.testing.assert_allclose(
        np.asarray(jp.rotation(*q[:3]) @ on_axis), np.asarray(jp.rotation(*p[:3]) @ on_axis), atol=1e-10
    )


@pytest.mark.parametrize("seed", range(4))
def test_a_turn_about_a_centre_keeps_that_point_of_the_body_where_p_moved_it(seed):
    """turned(p, v, c): the body point c goes where p takes it, and the rotation is G exp(v)."""
    import jaxlie

    from jaxpose._estimate import turned

    rng = np.random.default_rng(seed)
    p = jnp.asarray([*rng.uniform(-0.5, 0.5, 3), *rng.uniform(-0.1, 0.1, 3)])
    v = jnp.asarray(rng.normal(size=3) * 0.3)
    c = jnp.asarray(rng.uniform(-1.0, 1.0, 3))
    q = turned(p, v, c)
    G, H = jp.rotation(*p[:3]), jp.rotation(*q[:3])
    np.testing.assert_allclose(np.asarray(H), np.asarray(G @ jaxlie.SO3.exp(v).as_matrix()), atol=1e-10)
    np.testing.assert_allclose(np.asarray(H @ c + q[3:]), np.asarray(G @ c + p[3:]), atol=1e-10)


def _cylinder_side(axis_point, radius, seen_deg, rng, noise=0.0):
    """Points and outward normals (3, K) of the part of a cylinder along z, through
    `axis_point`, that a camera on the −y side sees (azimuths within ±seen_deg/2 of −y)."""
    k = 600
    azimuth = np.radians(-90.0 + rng.uniform(-seen_deg / 2, seen_deg / 2, k))
    normals = np.stack([np.cos(azimuth), np.sin(azimuth), np.zeros(k)])
    points = (
        np.asarray(axis_point)[:, None] + radius * normals + np.array([[0.0], [0.0], [1.0]]) * rng.uniform(-1, 1, k)
    )
    normals = normals + noise * rng.normal(size=normals.shape)
    return points, normals / np.linalg.norm(normals, axis=0)


@pytest.mark.parametrize("seed", range(3))
def test_the_symmetry_centre_of_a_seen_cylinder_side_is_on_its_axis(seed):
    """The visible side of a cylinder (its centroid lies off the axis, towards the camera):
    the centre comes out on the axis, across it, to within a millimetre with noise-free normals
    and a centimetre with normals 3° off."""
    from jaxpose._estimate import symmetry_centre

    rng = np.random.default_rng(seed)
    axis_point = np.array([*rng.uniform(-0.3, 0.3, 2), 0.0])
    radius = rng.uniform(0.4, 1.5)
    for noise, tol in ((0.0, 1e-3), (0.05, 1e-2)):
        points, normals = _cylinder_side(axis_point, radius, 150.0, rng, noise)
        centroid = points.mean(axis=1, keepdims=True)  # the plane frame's origin
        valid = jnp.ones(points.shape[1], bool)
        turn = jnp.array([0.0, 0.0, 0.26])
        centre = np.asarray(symmetry_centre(jnp.asarray(points - centroid), jnp.asarray(normals), valid, turn))
        expected = axis_point - centroid[:, 0]
        np.testing.assert_allclose(centre[:2], expected[:2], atol=tol)
        assert abs(centre[2]) < 1e-9  # nothing along the axis
        assert np.linalg.norm(expected[:2]) > 0.3 * radius  # the origin is well off the axis


def test_the_symmetry_centre_stays_at_the_origin_where_normals_fix_nothing():
    """A flat face seen head-on, its normals along the turn axis: the origin. A single face
    across the axis (the plane x = 0.5, turned about y): its normal lines fix the centre's
    height on the face (the points' mean z) and leave its depth to the pull towards the
    origin. No turn at all: zero."""
    from jaxpose._estimate import symmetry_centre

    rng = np.random.default_rng(0)
    u, v = rng.uniform(-1, 1, (2, 200))
    valid = jnp.ones(200, bool)
    along = lambda axis: jnp.tile(jnp.eye(3)[axis][:, None], (1, 200))  # noqa: E731
    disk = jnp.asarray(np.stack([u, v, np.zeros(200)]))
    centre = symmetry_centre(disk, along(2), valid, jnp.array([0.0, 0.0, 0.3]))
    np.testing.assert_allclose(np.asarray(centre), 0.0, atol=1e-6)
    face = jnp.asarray(np.stack([np.full(200, 0.5), u, v]))
    centre = symmetry_centre(face, along(0), valid, jnp.array([0.0, 0.3, 0.0]))
    np.testing.assert_allclose(np.asarray(centre), [0.0, 0.0, v.mean()], atol=1e-3 * abs(v.mean()) + 1e-9)
    none = symmetry_centre(disk + 2.0, along(2), valid, jnp.zeros(3))
    np.testing.assert_array_equal(np.asarray(none), 0.0)


@pytest.mark.parametrize(
    "challenger_angles, challenger_inliers, challenger_rms, best_after, other_after, ambiguous_after",
    [
        ((0.0, 0.0, 15.0), 0.0, 0.003, "best", "other", False),  # an inactive run changes nothing
        ((0.0, 0.0, 15.0), 0.675, 0.003, "best", "challenger", True),  # as good and apart: ambiguous
        ((0.0, 0.0, 15.0), 0.675, 0.002, "challenger", "best", True),  # a tie, smaller residuals: it wins, ambiguous
        ((0.0, 0.0, 15.0), 0.72, 0.003, "challenger", "best", False),  # clearly better and apart: it wins
        ((0.0, 0.0, 0.3), 0.72, 0.003, "challenger", "other", False),  # better, the same motion within 1°
        ((0.0, 0.0, 15.0), 0.60, 0.003, "best", "challenger", False),  # worse and apart: the runner-up
    ],
)
def test_a_contest_of_fits(
    challenger_angles, challenger_inliers, challenger_rms, best_after, other_after, ambiguous_after
):
    from jaxpose._estimate import contest

    best = _fine_result((0.0, 0.0, 0.0), 0.67)
    other = _fine_result((0.0, 0.2, 0.0), 0.66)  # the same motion as best within 1°
    challenger = _fine_result(challenger_angles, challenger_inliers, challenger_rms)
    named = {"best": best, "other": other, "challenger": challenger}
    new_best, new_other, ambiguous = contest(best, other, jnp.asarray(False), challenger, jp.Config())
    np.testing.assert_array_equal(np.asarray(new_best.params), np.asarray(named[best_after].params))
    np.testing.assert_array_equal(np.asarray(new_other.params), np.asarray(named[other_after].params))
    assert bool(ambiguous) == ambiguous_after


@pytest.mark.parametrize("best_rms, ambiguous_after", [(0.003, True), (0.0005, False)])
def test_a_turned_fit_within_the_turn_tie_makes_a_noisy_estimate_ambiguous(best_rms, ambiguous_after):
    """A fit turned about a near-symmetry axis that explains 1.5 % fewer current points than the
    best lies outside `FINE_TIE` but inside `TURN_TIE`: the best stays and the turned fit
    becomes the runner-up. The estimate is ambiguous when the best's residuals show range
    noise (3 mm), not when they do not (0.5 mm, below `EXACT_RMS`: `turn_tie` is `FINE_TIE`)."""
    from jaxpose._estimate import FINE_TIE, TURN_TIE, contest, turn_tie
    from jaxpose._fine import EXACT_RMS

    best = _fine_result((0.0, 0.0, 0.0), 0.67, best_rms)
    other = _fine_result((0.0, 0.2, 0.0), 0.66)
    turned = _fine_result((0.0, 0.0, 14.0), 0.655, 0.002)
    assert FINE_TIE < 0.67 - 0.655 < TURN_TIE
    assert float(turn_tie(best)) == (TURN_TIE if best_rms >= EXACT_RMS else FINE_TIE)
    new_best, new_other, ambiguous = contest(best, other, jnp.asarray(False), turned, jp.Config())
    np.testing.assert_array_equal(np.asarray(new_best.params), np.asarray(best.params))
    np.testing.assert_array_equal(np.asarray(new_other.params), np.asarray(turned.params))
    assert bool(ambiguous) == ambiguous_after


def test_the_boundary_passes_clouds_on_as_masked_floats():
    """`Cloud.floating`: integer points become the default float type and invalid rows zeros,
    so `estimate` runs them in the float program, never NaN from a row nobody reads."""
    ints = jp.Cloud(jnp.arange(12, dtype=jnp.int32).reshape(4, 3), jnp.array([True, True, False, True]))
    out = ints.floating()
    assert out.points.dtype == jnp.result_type(float)
    np.testing.assert_array_equal(np.asarray(out.points[2]), 0.0)
    np.testing.assert_array_equal(np.asarray(out.points[3]), [9.0, 10.0, 11.0])
    holes = jp.Cloud(jnp.array([[1.0, 2.0, 3.0], [jnp.nan, 0.0, 0.0]]), jnp.array([True, False]))
    assert bool(jnp.all(jnp.isfinite(holes.floating().points)))
    batch = jp.Cloud(jnp.ones((2, 3, 3)), jnp.array([[True, False, True], [False, True, True]]))
    np.testing.assert_array_equal(np.asarray(batch.floating().points[:, :, 0]), [[1, 0, 1], [0, 1, 1]])


@pytest.mark.slow
def test_a_dropped_fine_result_without_a_refine_is_not_converged(paper_clouds):
    """Without a refine, a fine-stage result that is dropped leaves the search's best on coarse
    cells, which no fit converged on: `converged` is False. Here the fine stage's fit (the
    paper's N5 variant 2, ≈ 12° from rest) lies beyond a ±1° box's reach (`within_reach`)."""
    from jaxpose._estimate import _box_stages

    box = jp.GlobalSearch(angle_box=np.radians(1.0), shift_box=0.01, recentre=0, population=8, generations=4)
    config = jp.Config(search=box, capacities=CONFIG.capacities)
    assert config.refine is None
    problem = jp.Problem.build(paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"], config)
    stages = eqx.filter_jit(_box_stages)(problem, config, jax.random.key(0))
    glob, p, converged, fine_kept = stages[0], stages[2], stages[3], stages[6]
    assert not bool(fine_kept)
    np.testing.assert_array_equal(np.asarray(p), np.asarray(glob.params))
    assert not bool(converged)


@pytest.mark.parametrize(
    "b_angles, b_inliers, b_conflict, b_wins, tied",
    [
        ((0.0, 0.0, 15.0), 0.70, 0.030, False, True),  # more inliers beyond the noise band, more conflict: a, ambiguous
        ((0.0, 0.0, 15.0), 0.60, 0.010, True, True),  # fewer inliers beyond the band, less conflict: b, ambiguous
        ((0.0, 0.0, 15.0), 0.665, 0.010, True, False),  # more inliers within the band, less conflict: b
        ((0.0, 0.0, 15.0), 0.635, 0.030, False, False),  # fewer inliers and more conflict: a
        ((0.0, 0.0, 15.0), 0.60, 0.0205, False, True),  # conflicts within CONFLICT_TIE: inliers, ambiguous
        ((0.0, 0.0, 15.0), 0.70, 0.0205, True, True),  # the same tie, b has more inliers: b wins, ambiguous
        ((0.0, 0.0, 0.3), 0.70, 0.030, True, False),  # the same motion within 1°: the inlier rule
        ((0.0, 0.0, 15.0), 0.70, np.nan, True, False),  # b's conflict not judged: the inlier rule
    ],
)
def test_fits_far_apart_are_weighed_by_what_the_views_saw(b_angles, b_inliers, b_conflict, b_wins, tied):
    """`prefers` with a config: between two live fits more than `Thresholds.ambiguous_deg`
    apart, the smaller free-space conflict wins whatever the inlier fractions; within 1°, where
    the conflicts lie within `CONFLICT_TIE`, or where a conflict is not judged (NaN), the
    inlier fraction (then the RMS) decides.
    `equally_good_and_apart` also ties fits apart whose conflicts lie within `CONFLICT_TIE`,
    and fits apart that the conflict and the inlier fraction rank oppositely, each beyond its
    tie (`disagree`; these fits show range noise, so the inlier band is `TURN_TIE`)."""
    from jaxpose._estimate import CONFLICT_TIE, equally_good_and_apart, prefers

    a = _fine_result((0.0, 0.0, 0.0), 0.65, conflict=0.020)
    b = _fine_result(b_angles, b_inliers, conflict=b_conflict)
    config = jp.Config()
    assert bool(prefers(a, b, config)) == b_wins
    assert bool(prefers(b, a, config)) == (not b_wins and not np.isclose(b_inliers, 0.65))
    assert bool(prefers(a, b)) == (b_inliers > 0.66)  # without a config: inliers alone
    assert bool(equally_good_and_apart(a, b, config)) == tied
    assert CONFLICT_TIE > abs(0.0205 - 0.020)


@pytest.mark.parametrize(
    "b_inliers, b_conflict, b_rms, expected",
    [
        (0.8301, 0.1006, 0.0002, True),  # the held-out noise-free upper stage: the measures disagree
        (0.8420, 0.1006, 0.0002, False),  # inliers within FINE_TIE noise-free: the conflict decides
        (0.8301, 0.1060, 0.0002, False),  # conflicts within CONFLICT_TIE: no ranking to disagree with
        (0.8301, 0.1006, 0.0030, False),  # the same shares under range noise: inliers within TURN_TIE
        (0.8650, 0.1006, 0.0002, False),  # b better by both measures
        (0.8301, np.nan, 0.0002, False),  # b's conflict not judged
    ],
)
def test_the_conflict_and_the_inlier_fraction_disagree(b_inliers, b_conflict, b_rms, expected):
    """`disagree`: the free-space conflict and the inlier fraction rank two fits oppositely,
    each beyond its tie (`CONFLICT_TIE`; `turn_tie` of the first fit: `FINE_TIE` without range
    noise, `TURN_TIE` with it). The first row is the held-out draw's noise-free upper stage
    (seed 5, #4): the truth's fit (a) explained 0.017 more of the current cloud, the fit 15°
    away about the long axis (b) conflicted 0.007 less, and was reported a success."""
    from jaxpose._estimate import disagree, equally_good_and_apart

    a = _fine_result((0.0, 0.0, 0.0), 0.8472, rms=b_rms, conflict=0.1074)
    b = _fine_result((0.0, 0.0, 15.0), b_inliers, rms=b_rms, conflict=b_conflict)
    assert bool(disagree(a, b)) == expected
    assert bool(disagree(b, a)) == expected
    if expected:
        assert bool(equally_good_and_apart(a, b, jp.Config()))


def test_the_truth_contradicts_the_views_less_than_a_turn_about_the_long_axis():
    """`free_space_conflict` on a noise-free upper-stage pair of the realistic benchmark (seed
    1, #3, where a 15° turn about the long axis explains more of the current cloud than the
    truth: the cylinder is a 24-sided prism). The true displacement puts fewer points where the
    other view saw through them than the truth turned by ±15° about the long axis, or than a
    motion 1 cm aside."""
    from jaxpose._capture import view_maps
    from jaxpose._estimate import free_space_conflict, symmetry_centre, symmetry_turns, turned
    from jaxpose._poses import displacement_from_motion
    from jaxpose._problem import _build, sized_config
    from jaxpose.evaluation import realistic

    case = realistic.make_cases(8, seed=1, names=("upper_stage",), levels=(0.0,), keep=lambda s: s.endswith("#3"))[0]
    prev, curr = case.prev.floating(), case.curr.floating()
    config = sized_config(prev, curr, jp.Config())

    @jax.jit
    def conflicts(prev, curr, rotation, translation):
        """The conflicts of the truth, of the truth turned by ±15°, and of a motion 1 cm aside,
        with the turns' size, in one compiled program (op by op, the build and the view maps
        take tens of seconds)."""
        problem = _build(prev, curr, config)
        truth = displacement_from_motion(problem.frame.origin, problem.frame.axes, rotation, translation)
        truth = truth.astype(problem.d.dtype)
        views = view_maps(problem)
        turns = symmetry_turns(problem.frame, config)
        fine = problem.fine
        centre = symmetry_centre(fine.points, fine.normals, fine.valid, turns[0])
        right = free_space_conflict(problem, truth, views)
        wrong = jnp.stack([free_space_conflict(problem, turned(truth, t, centre), views) for t in turns])
        aside = free_space_conflict(problem, truth.at[4].add(0.01), views)
        return right, wrong, aside, jnp.linalg.norm(turns[0])

    right, wrong, aside, turn = (np.asarray(x) for x in conflicts(prev, curr, case.rotation, case.translation))
    assert turn > 0  # the view is nearly symmetric
    assert right < wrong.min() and right < aside, (right, wrong, aside)
