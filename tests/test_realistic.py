"""Any target, any view: capacities sized from the clouds, the voxel-grid neighbour search
against brute force, the ToF sensor model, and the realistic benchmark's pairs."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose import _neighbours as neighbours
from jaxpose import targets
from jaxpose._fine import fine_refine
from jaxpose._poses import displacement_from_motion, motion_from_displacement
from jaxpose._problem import bucket, sized_batch_config, sized_config
from jaxpose.evaluation import realistic
from jaxpose.sim import _shapes as shapes


def test_buckets_are_few_and_cover_the_count():
    sizes = {bucket(n, 64) for n in range(1, 5000)}
    assert sorted(sizes) == [64, 128, 256, 512, 1024, 2048, 4096, 8192]
    for n in (1, 63, 64, 65, 97, 1000, 4097):
        b = bucket(n, 64)
        assert b >= n and b <= max(64, 2 * n - 1)


def test_voxel_grid_nearest_matches_brute_force_within_reach():
    rng = np.random.default_rng(0)
    # A noisy, sampled surface (a bent sheet) and queries near it.
    u, v = rng.uniform(-0.5, 0.5, (2, 3000))
    pts = np.stack([u, v, 0.2 * np.abs(u) + 0.003 * rng.normal(size=u.size)]).astype(np.float32)
    valid = rng.uniform(size=u.size) > 0.1
    queries = pts[:, :500] + 0.01 * rng.normal(size=(3, 500)).astype(np.float32)
    step = float(neighbours.voxel_spacing(jnp.asarray(pts), jnp.asarray(valid)))
    grid = neighbours.voxel_grid(jnp.asarray(pts), jnp.asarray(valid), 2 * step)
    idx, dist = neighbours.nearest(grid, jnp.asarray(queries), 16)
    d2 = ((queries.T[:, None, :] - pts.T[None]) ** 2).sum(-1)
    d2[:, ~valid] = np.inf
    exact = np.sqrt(d2.min(1))
    reach = exact < 2 * step
    assert reach.mean() > 0.5
    np.testing.assert_allclose(np.asarray(dist)[reach], exact[reach], rtol=1e-5)
    assert np.all(np.asarray(dist) >= exact - 1e-6)  # never nearer than the truth
    np.testing.assert_allclose(
        np.linalg.norm(pts[:, np.asarray(idx)] - queries, axis=0)[reach], exact[reach], rtol=1e-5
    )
    knn, kd2 = neighbours.k_nearest(grid, jnp.asarray(queries), 5, 16)
    kd2 = np.asarray(kd2)
    exact5 = np.sort(d2, axis=1)[:, :5]
    within = exact5[:, -1] < (2 * step) ** 2
    np.testing.assert_allclose(kd2[within], exact5[within], rtol=1e-4, atol=1e-9)


def test_first_minimum_is_argmin_with_ties_and_rows_of_inf():
    # Rows as the neighbour searches make them: squared distances on a coarse lattice (many
    # exact ties), inf for slots outside the query's voxels, and whole rows of inf.
    rng = np.random.default_rng(4)
    values = rng.integers(0, 6, (400, 37)).astype(np.float32) * 0.25
    values[rng.uniform(size=values.shape) < 0.4] = np.inf
    values[::7] = np.inf
    index, low = neighbours.first_minimum(jnp.asarray(values))
    np.testing.assert_array_equal(np.asarray(index), np.argmin(values, axis=1))
    np.testing.assert_array_equal(np.asarray(low), values.min(axis=1))
    assert np.all(np.asarray(index)[::7] == 0)


def test_a_step_of_graph_descent_finds_the_nearest_of_a_query_that_moved_little():
    # A noisy sampled surface, its 20-nearest-neighbour graph, and queries that were nearest
    # to some point and then moved by half a sampling step: the new nearest is among the old
    # one and its neighbours, so the graph step finds the brute-force nearest.
    rng = np.random.default_rng(1)
    u, v = rng.uniform(-0.5, 0.5, (2, 3000))
    pts = np.stack([u, v, 0.2 * np.abs(u) + 0.003 * rng.normal(size=u.size)]).astype(np.float32)
    valid = np.ones(u.size, bool)
    step = float(neighbours.voxel_spacing(jnp.asarray(pts), jnp.asarray(valid)))
    grid = neighbours.voxel_grid(jnp.asarray(pts), jnp.asarray(valid), 2 * step)
    graph, _ = neighbours.k_nearest(grid, jnp.asarray(pts), 20, 16)
    start = pts[:, :400] + 0.2 * step * rng.normal(size=(3, 400)).astype(np.float32)
    guess, _ = neighbours.nearest(grid, jnp.asarray(start), 16)
    direction = rng.normal(size=(3, 400))
    moved = (start + 0.5 * step * direction / np.linalg.norm(direction, axis=0)).astype(np.float32)
    idx, dist = neighbours.nearest_in_graph(jnp.asarray(pts), graph, guess, jnp.asarray(moved))
    exact = np.sqrt(((moved.T[:, None, :] - pts.T[None]) ** 2).sum(-1))
    np.testing.assert_allclose(np.asarray(dist), exact.min(1), rtol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(pts[:, np.asarray(idx)] - moved, axis=0), np.asarray(dist), rtol=1e-5)
    # Moved far (ten steps), one step of descent is no longer exact: it returns a real point
    # at its true distance, never nearer than the nearest.
    far = (start + 10 * step * direction / np.linalg.norm(direction, axis=0)).astype(np.float32)
    idx, dist = neighbours.nearest_in_graph(jnp.asarray(pts), graph, guess, jnp.asarray(far))
    exact = np.sqrt(((far.T[:, None, :] - pts.T[None]) ** 2).sum(-1)).min(1)
    assert np.all(np.asarray(dist) >= exact - 1e-6) and np.any(np.asarray(dist) > exact + 1e-4)
    np.testing.assert_allclose(np.linalg.norm(pts[:, np.asarray(idx)] - far, axis=0), np.asarray(dist), rtol=1e-5)


def _sheet(seed: int, count: int = 3000):
    """A noisy, sampled bent sheet (SoA, float32) with 10 % of its points invalid."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(-0.5, 0.5, (2, count))
    pts = np.stack([u, v, 0.2 * np.abs(u) + 0.003 * rng.normal(size=u.size)]).astype(np.float32)
    return rng, pts, rng.uniform(size=u.size) > 0.1


@pytest.mark.parametrize("slots", [16, 2])
def test_exact_radius_holds_every_point_the_search_reads_and_zero_where_a_column_overflows(slots):
    # Every valid point within a query's exact radius is among its candidates (brute force);
    # with 2 slots most of the sheet's columns overflow, and those queries' radius is 0.
    rng, pts, valid = _sheet(5)
    step = float(neighbours.voxel_spacing(jnp.asarray(pts), jnp.asarray(valid)))
    grid = neighbours.voxel_grid(jnp.asarray(pts), jnp.asarray(valid), 2 * step)
    queries = (pts[:, :600] + 0.02 * rng.normal(size=(3, 600))).astype(np.float32)
    found = neighbours.windows(grid, jnp.asarray(queries), slots)
    radius = np.asarray(neighbours.exact_radius(grid, jnp.asarray(queries), found, slots))
    cand = neighbours.candidates(grid, jnp.asarray(queries), slots)
    read = np.asarray(grid.order)[np.asarray(cand.sorted_index)]
    real = np.asarray(cand.real)
    d = np.sqrt(((queries.T[:, None, :] - pts.T[None]) ** 2).sum(-1))
    for i in range(queries.shape[1]):
        inside = np.flatnonzero(valid & (d[i] < radius[i]))
        assert set(inside) <= set(read[i][real[i]])
    h = 2 * step
    exact = radius > 0
    assert np.all((radius[exact] >= h * (1 - 1e-5)) & (radius[exact] <= 1.5 * h * (1 + 1e-5)))
    assert exact.mean() > 0.9 if slots == 16 else exact.mean() < 0.6


def test_graph_radius_bounds_every_point_outside_the_neighbourhood():
    # No valid point outside a point's k-nearest row lies nearer to it than its graph radius.
    _, pts, valid = _sheet(6)
    step = float(neighbours.voxel_spacing(jnp.asarray(pts), jnp.asarray(valid)))
    grid = neighbours.voxel_grid(jnp.asarray(pts), jnp.asarray(valid), 2 * step)
    graph, d2 = neighbours.k_nearest(grid, jnp.asarray(pts), 20, 16)
    found = neighbours.windows(grid, jnp.asarray(pts), 16)
    radius = np.asarray(neighbours.graph_radius(grid, jnp.asarray(pts), d2, found, 16))
    graph = np.asarray(graph)
    assert np.median(radius[valid]) > 1.5 * step
    d = np.sqrt(((pts.T[:, None, :] - pts.T[None]) ** 2).sum(-1))
    for i in np.flatnonzero(valid)[:800]:
        outside = valid.copy()
        outside[graph[i]] = False
        outside[i] = False
        assert np.all(d[i][outside] >= radius[i] * (1 - 1e-5))


def test_certified_graph_matches_are_the_nearest_and_the_bound_never_exceeds_it():
    # Queries that moved by 0.3–3 sampling steps from their last nearest: where the graph step
    # says "certain", its answer is the brute-force nearest; everywhere its bound is at most
    # the nearest distance; most small moves are certified and few large ones are.
    rng, pts, valid = _sheet(7)
    step = float(neighbours.voxel_spacing(jnp.asarray(pts), jnp.asarray(valid)))
    grid = neighbours.voxel_grid(jnp.asarray(pts), jnp.asarray(valid), 2 * step)
    graph, d2 = neighbours.k_nearest(grid, jnp.asarray(pts), 20, 16)
    radius = neighbours.graph_radius(grid, jnp.asarray(pts), d2, neighbours.windows(grid, jnp.asarray(pts), 16), 16)
    radius = jnp.where(jnp.asarray(valid), radius, 0.0)
    start = pts[:, valid][:, :500] + 0.2 * step * rng.normal(size=(3, 500)).astype(np.float32)
    guess, _ = neighbours.nearest(grid, jnp.asarray(start), 16)
    direction = rng.normal(size=(3, 500))
    direction /= np.linalg.norm(direction, axis=0)
    exact_of = lambda q: np.where(valid[None], np.sqrt(((q.T[:, None, :] - pts.T[None]) ** 2).sum(-1)), np.inf)  # noqa: E731
    shares = []
    for moves in (0.3, 3.0):
        q = (start + moves * step * direction).astype(np.float32)
        idx, dist, certain, bound = map(
            np.asarray, neighbours.certified_in_graph(jnp.asarray(pts), graph, radius, guess, jnp.asarray(q))
        )
        exact = exact_of(q)
        nearest = exact.min(1)
        np.testing.assert_allclose(dist[certain], nearest[certain], rtol=1e-5)
        np.testing.assert_array_equal(idx[certain], exact.argmin(1)[certain])
        assert np.all(bound <= nearest * (1 + 1e-5) + 1e-7)
        shares.append(certain.mean())
    assert shares[0] > 0.5 and shares[1] < 0.2


@pytest.mark.parametrize("count, line", [(3, False), (16, False), (60, True)])
def test_voxel_grid_search_of_a_few_points_reads_windows_at_the_end_of_the_order(count, line):
    # Fewer points than slots, or a line of points a few per column: windows at the end of
    # the key order are clamped to the end of the arrays and must still find every point.
    rng = np.random.default_rng(count)
    pts = rng.uniform(0.0, 0.1, (3, count)).astype(np.float32)
    if line:
        pts[0] = np.linspace(0.0, 6.0, count)
    grid = neighbours.voxel_grid(jnp.asarray(pts), jnp.ones(count, bool), 0.2)
    queries = pts + 0.001
    idx, dist = neighbours.nearest(grid, jnp.asarray(queries), 16)
    exact = np.sqrt(((queries.T[:, None, :] - pts.T[None]) ** 2).sum(-1))
    np.testing.assert_array_equal(np.asarray(idx), exact.argmin(1))
    np.testing.assert_allclose(np.asarray(dist), exact.min(1), rtol=1e-5)


def test_tof_noise_grows_with_range_and_flying_pixels_sit_between_surfaces():
    target = targets.n5()
    R = np.asarray(jp.rotation(0.4, 0.5, 0.2))
    key = jax.random.key(3)
    spreads = []
    for z in (3.0, 6.0):
        camera = jp.Camera.camcube2(noise_sigma=0.01, noise_range_ref=5.0)
        noisy = jp.simulate(camera, target, R, np.array([0, 0, z]), key=key)
        clean = jp.simulate(jp.Camera.camcube2(), target, R, np.array([0, 0, z]))
        both = np.asarray(noisy.valid & clean.valid)
        spreads.append(np.median(np.linalg.norm(np.asarray(noisy.points - clean.points)[both], axis=1)))
    assert spreads[1] > 1.6 * spreads[0]  # σ ∝ range: twice the range, about twice the noise
    flying = jp.simulate(jp.Camera.camcube2(flying=1.0), target, R, np.array([0, 0, 4.0]), key=key)
    clean = jp.simulate(jp.Camera.camcube2(), target, R, np.array([0, 0, 4.0]))
    moved = np.linalg.norm(np.asarray(flying.points - clean.points), axis=1) > 1e-6
    assert 0 < moved.sum() < 0.2 * int(clean.num_valid)  # only depth-edge pixels mix
    with pytest.raises(ValueError, match="PRNG key"):
        jp.simulate(jp.Camera.camcube2(flying=0.5), target, R, np.array([0, 0, 4.0]))


def test_built_in_targets_are_the_advertised_sizes():
    for name in targets.BUILT_IN:
        extent = realistic._extent(getattr(targets, name)())
        assert 0.9 < extent < 4.0, (name, extent)
    assert realistic._extent(targets.satellite()) == pytest.approx(3.8, abs=0.01)
    assert realistic._extent(targets.debris()) == pytest.approx(1.6, abs=0.01)


@pytest.mark.parametrize(
    "ranges", [("near", "far"), pytest.param(("middle",), marks=pytest.mark.slow)], ids=["2-and-7-m", "4-m"]
)
@pytest.mark.parametrize("name", targets.BUILT_IN)
def test_every_built_in_target_is_accepted_at_2_4_and_7_m(name, ranges):
    """No capacity is the user's problem: each target at a random attitude at 2, 4 and 7 m
    (nearer when the range gate would cut it) gives a usable problem with the default config.
    The default run takes the two ends of the range (the largest and the smallest clouds);
    4 m runs under -m slow."""
    target = getattr(targets, name)()
    camera = jp.Camera.camcube2(noise_sigma=0.01, noise_range_ref=5.0, dropout=0.1, flying=0.5)
    extent = realistic._extent(target)
    rng = np.random.default_rng(hash(name) % 2**32)
    distances = {"near": 2.0, "middle": 4.0, "far": 7.0 - extent / 2}
    for label, z in distances.items():
        R0 = realistic._random_rotation(rng)  # each range its own draw, whichever ranges run
        R1 = realistic._axis_angle(rng.normal(size=3), math.radians(5.0)) @ R0
        if label not in ranges:
            continue
        t = np.array([0.0, 0.0, z])
        keys = jax.random.split(jax.random.key(int(z * 10)))
        prev, curr = (jp.simulate(camera, target, R, t, key=k) for R, k in ((R0, keys[0]), (R1, keys[1])))
        config = sized_config(prev, curr, jp.Config())
        problem = jp.Problem.build(prev, curr, config)  # raises on any unusable pair
        assert int(problem.status) == 0
        assert config.capacities.max_points >= int(curr.num_valid) and config.capacities.grid_cells >= 32


def test_a_mesh_4_m_across_is_accepted_and_estimated():
    v, f = shapes.rock(axes=(4.0, 2.0, 1.2), seed=5)
    target = targets.Mesh.create(v, f)
    camera = jp.Camera.camcube2()
    R0 = np.asarray(jp.rotation(0.3, -0.2, 0.5))
    R1 = realistic._axis_angle(np.array([0.2, 1.0, 0.1]), math.radians(4.0)) @ R0
    t = np.array([0.0, 0.0, 6.0])
    prev, curr = jp.simulate(camera, target, R0, t), jp.simulate(camera, target, R1, t)
    est = jp.estimate(prev, curr, key=jax.random.key(0))
    angle = math.degrees(float(jp.rotation_angle(est.rotation, R1 @ R0.T)))
    assert angle < 0.1, angle


@pytest.fixture(scope="module")
def head_on():
    """N1 centred on the optical axis, face-on at 4 m, turned 3° (noise-free): a `Case`."""
    target, camera = targets.n1(), jp.Camera.camcube2()
    R0 = np.eye(3)
    R1 = realistic._axis_angle(np.array([0.3, 1.0, 0.2]), math.radians(3.0))
    t0, t1 = np.array([0.0, 0.0, 4.0]), np.array([0.02, -0.01, 4.03])
    prev, curr = jp.simulate(camera, target, R0, t0), jp.simulate(camera, target, R1, t1)
    return realistic.Case("n1", 0.0, 0, prev, curr, R1, t1 - R1 @ t0, 3.0)


@pytest.fixture(scope="module")
def close_view():
    """The realistic benchmark's second noise-free N5 pair: a close view of ≈ 19 000 points."""
    return realistic.make_cases(2, names=("n5",), levels=(0.0,))[1]


@pytest.fixture(scope="module")
def accuracy_config(head_on, close_view):
    """The default `Config()` sized once for both accuracy pairs below, so that they share one
    compiled program (what sizing each from its data gives is the acceptance tests' concern)."""
    return sized_batch_config([(c.prev, c.curr) for c in (head_on, close_view)], jp.Config())


def test_one_face_seen_head_on_is_accepted_and_found(head_on, accuracy_config):
    """A camera produces coplanar clouds: N1 centred on the optical axis, face-on, shows its
    front face alone. The pair is accepted (no ValueError) and the motion found within the
    realistic benchmark's bounds (< 1°, < 5 cm): the face's outline fixes the turn in its plane."""
    case = head_on
    normal_spread = np.ptp(np.asarray(case.prev.compact())[:, 2])
    assert normal_spread < 1e-4  # the previous cloud is one plane
    sized_config(case.prev, case.curr, jp.Config())  # accepted: raises on a pair it would refuse
    est = jp.estimate(case.prev, case.curr, accuracy_config, key=jax.random.key(0))
    errors = realistic.errors(case, est.rotation, est.translation)
    assert errors["found"], errors


def test_a_close_view_is_exact(close_view, accuracy_config):
    """A noise-free N5 view of ≈ 19 000 points (the realistic benchmark's second N5 pair), more
    than the fine stage fits (`FineStage.points`): the default call still meets the
    noise-free goal, 0.01° and 0.01 cm."""
    case = close_view
    assert int(case.curr.num_valid) > 4 * accuracy_config.fine.points
    est = jp.estimate(case.prev, case.curr, accuracy_config, key=jax.random.key(1))
    errors = realistic.errors(case, est.rotation, est.translation)
    assert bool(est.success)
    assert errors["rotation_error_deg"] < 0.01 and errors["centroid_error_cm"] < 0.01, errors


def test_without_a_refine_its_slot_holds_the_search_best_and_its_soft_score(close_view, accuracy_config):
    """`Config()` has no refine: `est.refine` is the search's best, scored on the full problem
    (in one batched evaluation with the estimate), converged, with no steps."""
    case = close_view
    assert accuracy_config.refine is None
    est = jp.estimate(case.prev, case.curr, accuracy_config, key=jax.random.key(1))
    np.testing.assert_array_equal(np.asarray(est.refine.params), np.asarray(est.search.params))
    assert int(est.refine.steps) == 0 and bool(est.refine.converged)
    problem = jp.Problem.build(case.prev, case.curr, accuracy_config)
    expected = jax.jit(jp.soft_score)(est.search.params, problem)
    np.testing.assert_allclose(float(est.refine.score), float(expected), rtol=1e-9)
    assert float(est.refine.score) != float(est.soft)  # two points scored, not one twice


def test_a_kept_benchmark_pair_is_the_same_pair_as_in_the_whole_set():
    """`make_cases(keep=...)` simulates only the pairs whose label it accepts, each the same
    draw as in the whole set (its own seed), so a targeted experiment runs the benchmark's
    pairs without simulating the rest."""
    whole = realistic.make_cases(2, names=("n1",), levels=(0.0, 0.5))
    kept = realistic.make_cases(2, names=("n1",), levels=(0.0, 0.5), keep=lambda label: label == "n1 σ0.5 #1")
    assert [case.label for case in kept] == ["n1 σ0.5 #1"] == [whole[3].label]
    np.testing.assert_array_equal(np.asarray(kept[0].prev.points), np.asarray(whole[3].prev.points))
    np.testing.assert_array_equal(np.asarray(kept[0].curr.points), np.asarray(whole[3].curr.points))
    np.testing.assert_array_equal(kept[0].rotation, whole[3].rotation)


def test_benchmark_draws_share_one_simulate_program_and_the_clouds_are_unchanged():
    """`draw_pair` passes the camera's floats as arrays (`traced_camera`): pairs with other
    dropouts and noise levels reuse one compiled `simulate` instead of compiling their own
    (a float field is static to `eqx.filter_jit`), and the clouds are those of the float
    camera."""
    traces = []

    def counted(*args):
        traces.append(1)
        return jp.simulate(*args)

    sim = eqx.filter_jit(counted)
    target = targets.n1()
    near = realistic.nearest_distance(target)
    drawn = [
        realistic.draw_pair(sim, target, near, sigma, np.random.default_rng(i), 1.0, 15.0)
        for i, sigma in enumerate((0.5, 1.0, 2.0))
    ]
    assert len(traces) == 1
    camera = jp.Camera.camcube2(noise_sigma=0.01, noise_range_ref=realistic.RANGE_REF, dropout=0.2, flying=0.5)
    R, t, key = jnp.eye(3), jnp.array([0.0, 0.0, 4.0]), jax.random.key(3)
    as_floats = jp.simulate(camera, target, R, t, key)
    as_arrays = jax.jit(jp.simulate)(realistic.traced_camera(camera), target, R, t, key)
    np.testing.assert_array_equal(np.asarray(as_floats.valid), np.asarray(as_arrays.valid))
    np.testing.assert_allclose(np.asarray(as_floats.points), np.asarray(as_arrays.points), atol=1e-12)
    assert all(int(np.sum(np.asarray(d.prev.valid))) > 100 for d in drawn)


def test_jit_users_size_a_config_from_the_camera_and_extent():
    config = jp.Config().sized_for(jp.Camera.camcube2(), extent=5.0)
    assert config.capacities.grid_cells >= (1 + 2 * 0.2) * 5.0 / 0.026
    assert config.capacities.max_points <= 204 * 204 and config.capacities.max_cells >= 2 * math.pi * 5.0 / 0.026


@pytest.mark.slow
def test_a_dense_previous_side_moves_the_fine_minimum_towards_the_truth():
    """`FineStage.prev_points` beyond `points` keeps more of the previous cloud: on a noisy
    upper stage (σ 0.5 cm, ≈ 11,000 points a cloud; `make_cases`' second draw at that level) the fine
    stage's own minimum, reached from the true motion, lies within 0.1° and 0.1 cm of it with
    every previous point, and more than twice as far in rotation with 4096 evenly thinned
    ones (the default): a coarser previous side gives coarser matches and neighbourhood
    planes, and the turn about the long axis is fixed only by the small fittings."""
    case = realistic.make_cases(2, names=("upper_stage",), levels=(0.5,))[1]
    assert int(case.prev.num_valid) > 2 * jp.FineStage().points
    errors = {}
    for label, prev_points in (("all", 2**20), ("default", None)):
        config = sized_config(case.prev, case.curr, jp.Config(fine=jp.FineStage(prev_points=prev_points)))
        problem = jp.Problem.build(case.prev, case.curr, config)
        kept = int(problem.fine.valid.sum())
        # Every slot is filled; a point with fewer than 3 neighbours in reach has no plane
        # (about 2 % of the thinned side, where neighbours lie farther apart).
        assert kept >= 0.97 * min(int(case.prev.num_valid), prev_points or jp.FineStage().points)
        truth = displacement_from_motion(problem.frame.origin, problem.frame.axes, case.rotation, case.translation)
        fit = fine_refine(problem, config, truth.astype(problem.d.dtype))
        R, t = motion_from_displacement(problem.frame.origin, problem.frame.axes, fit.params)
        errors[label] = realistic.errors(case, R, t)
    assert errors["all"]["rotation_error_deg"] < 0.1 and errors["all"]["centroid_error_cm"] < 0.1, errors
    assert errors["default"]["rotation_error_deg"] > 2 * errors["all"]["rotation_error_deg"], errors


@pytest.mark.slow
def test_two_way_residuals_move_the_fine_minimum_towards_the_truth():
    """`FineStage.symmetric` also fits the previous points to the current side's planes: on the
    noisy mesh debris (σ 0.5 cm, `make_cases`' first draw of it at that level) the fine stage's
    own minimum, reached from the true motion, lies closer to it in rotation and less than
    0.6 times as far in centroid than the one-way fit's (measured in float64: 0.123° and 0.106
    cm against 0.180° and 0.214 cm)."""
    case = realistic.make_cases(1, names=("debris",), levels=(0.5,))[0]
    errors = {}
    for symmetric in (False, True):
        config = sized_config(case.prev, case.curr, jp.Config(fine=jp.FineStage(symmetric=symmetric)))
        problem = jp.Problem.build(case.prev, case.curr, config)
        assert (problem.fine_back is not None) == symmetric
        truth = displacement_from_motion(problem.frame.origin, problem.frame.axes, case.rotation, case.translation)
        fit = fine_refine(problem, config, truth.astype(problem.d.dtype))
        assert bool(fit.converged)
        R, t = motion_from_displacement(problem.frame.origin, problem.frame.axes, fit.params)
        errors[symmetric] = realistic.errors(case, R, t)
    assert errors[True]["rotation_error_deg"] < 0.8 * errors[False]["rotation_error_deg"], errors
    assert errors[True]["centroid_error_cm"] < 0.6 * errors[False]["centroid_error_cm"], errors


@pytest.mark.slow
def test_a_confident_wrong_estimate_with_an_equally_good_fit_apart_is_no_success():
    """The realistic benchmark's satellite at σ 2 cm, #6, as the benchmark runs it (float32, its
    key): the fits from the search's best and from rest end about 3.1° and 3.85° from the truth,
    a local minimum each, with inlier fractions 0.007 apart; the estimate's covariance
    predicts 0.1°. The spread between the two fits (0.76° in the committed run) makes the
    status uncertain: never a confident wrong answer (`Estimate.spread`)."""
    label = "satellite σ2 #6"
    case = realistic.make_cases(8, keep=lambda text: text == label)[0]
    position = (targets.BUILT_IN.index("satellite") * len(realistic.LEVELS_CM) + realistic.LEVELS_CM.index(2.0)) * 8 + 6
    with jax.enable_x64(False):  # the benchmark's precision: the tests run in float64
        prev, curr = (jp.Cloud(c.masked_points.astype(jnp.float32), c.valid) for c in (case.prev, case.curr))
        est = jp.estimate(prev, curr, key=jax.random.fold_in(jax.random.key(0), position))
        found = realistic.errors(case, est.rotation, est.translation)["found"]
    assert found or not bool(est.success), (label, float(est.spread))
    if not found:
        assert math.degrees(float(est.spread)) > 0.5
