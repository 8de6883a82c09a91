"""The simulator against an independent numpy ray caster (Möller–Trumbore on trimesh's own
box and sphere meshes, float64), plus the paper's cloud sizes and the input contract."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from conftest import T_PAPER, paper_rotation

import jaxpose as jp


def numpy_ray_cast(camera, triangles, R, t):
    """First hit of every pixel ray with a triangle soup (target frame), written from scratch."""
    W, H = camera.width, camera.height
    x = (np.arange(W) - (W - 1) / 2) / (W / 2) * float(camera.tan_half_x)
    y = (np.arange(H) - (H - 1) / 2) / (H / 2) * float(camera.tan_half_y)
    X, Y = np.meshgrid(x, y)  # rows = v, columns = u
    dirs = np.stack([X.ravel(), Y.ravel(), np.ones(W * H)], 1)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    tri = np.asarray(triangles) @ np.asarray(R).T + np.asarray(t)
    best = np.full(len(dirs), np.inf)
    for v0, v1, v2 in tri:
        e1, e2 = v1 - v0, v2 - v0
        pvec = np.cross(dirs, e2)
        det = pvec @ e1
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1 / det
            u = (-v0 @ pvec.T) * inv
            qvec = np.cross(-v0, e1)
            v = (dirs @ qvec) * inv
            dist = (e2 @ qvec) * inv
        hit = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (dist > 0)
        best = np.where(hit & (dist < best), dist, best)
    valid = np.isfinite(best) & (best >= float(camera.range_min)) & (best <= float(camera.range_max))
    return np.where(valid[:, None], dirs * np.where(valid, best, 0)[:, None], 0.0), valid


def trimesh_boxes(boxes):
    tris = []
    for c, h, Rb in zip(
        np.asarray(boxes.centers), np.asarray(boxes.half_sizes), np.asarray(boxes.rotations), strict=True
    ):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rb, c
        tris.append(trimesh.creation.box(extents=2 * h, transform=T).triangles)
    return np.concatenate(tris)


def random_rotation(seed):
    return np.asarray(jax.random.orthogonal(jax.random.key(seed), 3)) * 1.0


def proper(R):
    return R if np.linalg.det(R) > 0 else -R


CASES = [("n1", s) for s in range(2)] + [("n5", s) for s in range(2)] + [("sphere", s) for s in range(1)]


@pytest.mark.parametrize("shape,seed", CASES)
def test_simulator_matches_numpy_ray_caster(camera, shape, seed):
    rng = np.random.default_rng(seed)
    R = proper(random_rotation(seed))
    t = np.array([0.0, 0.0, 5.5]) + rng.normal(scale=0.3, size=3)
    if shape == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.6)
        target = jp.targets.Mesh.create(mesh.vertices, mesh.faces)
        reference_tris = mesh.triangles
    else:
        target = getattr(jp.targets, shape)()
        reference_tris = trimesh_boxes(target)
    cloud = jp.simulate(camera, target, R, t)
    ref_points, ref_valid = numpy_ray_cast(camera, reference_tris, R, t)
    valid = np.asarray(cloud.valid)
    disagree = np.mean(valid != ref_valid)
    assert disagree <= 1e-3, f"{disagree:.4%} of pixels disagree"
    both = valid & ref_valid
    assert both.sum() > 1000
    err = np.abs(np.asarray(cloud.points)[both] - ref_points[both]).max()
    assert err < 1e-5, err


def test_mesh_path_equals_box_path(camera):
    target = jp.targets.n5()
    mesh = jp.targets.Mesh(target.triangles())
    R, t = paper_rotation("previous"), jnp.asarray(T_PAPER)
    a, b = jp.simulate(camera, target, R, t), jp.simulate(camera, mesh, R, t)
    assert np.mean(np.asarray(a.valid) != np.asarray(b.valid)) <= 1e-3
    both = np.asarray(a.valid & b.valid)
    assert np.abs(np.asarray(a.points)[both] - np.asarray(b.points)[both]).max() < 1e-9


@pytest.mark.parametrize("pose,expected", [("previous", 4194), ("variant2", 4822)])
def test_paper_n5_cloud_sizes(paper_clouds, pose, expected):
    n = int(paper_clouds["n5", pose].num_valid)
    assert abs(n - expected) <= 0.005 * expected, n


def test_jit_and_vmap_over_poses_and_keys(camera):
    target = jp.targets.n5()
    cam = jp.Camera.camcube2(noise_sigma=0.01, dropout=0.1)
    Rs = jnp.stack([paper_rotation("previous"), paper_rotation("variant2")])
    ts = jnp.stack([jnp.asarray(T_PAPER), jnp.asarray(T_PAPER) + 0.1])
    keys = jax.random.split(jax.random.key(0), 2)
    batch = jax.jit(jax.vmap(jp.simulate, (None, None, 0, 0, 0)))(cam, target, Rs, ts, keys)
    for i in range(2):
        one = jp.simulate(cam, target, Rs[i], ts[i], keys[i])
        np.testing.assert_array_equal(np.asarray(batch.valid[i]), np.asarray(one.valid))
        np.testing.assert_allclose(np.asarray(batch.points[i]), np.asarray(one.points), atol=1e-12)


def test_noise_acts_along_the_ray_and_dropout_removes_points(camera):
    target = jp.targets.n5()
    R, t = paper_rotation("previous"), jnp.asarray(T_PAPER)
    clean = jp.simulate(camera, target, R, t)
    cam = jp.Camera.camcube2(noise_sigma=0.01, dropout=0.2)
    noisy = jp.simulate(cam, target, R, t, key=jax.random.key(3))
    both = np.asarray(clean.valid & noisy.valid)
    a, b = np.asarray(clean.points)[both], np.asarray(noisy.points)[both]
    cos = np.sum(a * b, 1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    np.testing.assert_allclose(cos, 1.0, atol=1e-12)  # same ray
    dr = np.linalg.norm(b, axis=1) - np.linalg.norm(a, axis=1)
    assert 0.008 < dr.std() < 0.012 and abs(dr.mean()) < 0.002
    kept = both.sum() / int(clean.num_valid)
    assert 0.76 < kept < 0.84


def test_range_gate(camera):
    far = jp.simulate(camera, jp.targets.n1(), jnp.eye(3), jnp.array([0.0, 0.0, 8.0]))
    assert int(far.num_valid) == 0
    near = jp.simulate(jp.Camera.camcube2(range_max=5.0), jp.targets.n1(), jnp.eye(3), jnp.array([0.0, 0.0, 5.2]))
    assert int(near.num_valid) > 0  # front face at 4.83 m
    assert np.linalg.norm(near.compact(), axis=1).max() <= 5.0


@pytest.mark.parametrize(
    "make",
    [
        lambda c, tg: jp.simulate(c, tg, jnp.eye(3), jnp.array([0.0, np.nan, 5.0])),
        lambda c, tg: jp.simulate(c, tg, jnp.eye(3) * np.inf, jnp.array([0.0, 0.0, 5.0])),
        lambda c, tg: jp.simulate(c, tg, jnp.eye(3), jnp.array([0.0, 5.0])),
        lambda c, tg: jp.simulate(c, tg, jnp.eye(2), jnp.array([0.0, 0.0, 5.0])),
        lambda c, tg: jp.simulate(c, tg, 2 * jnp.eye(3), jnp.array([0.0, 0.0, 5.0])),
        lambda c, tg: jp.simulate(jp.Camera.camcube2(noise_sigma=0.01), tg, jnp.eye(3), jnp.array([0.0, 0.0, 5.0])),
        lambda c, tg: jp.targets.Boxes.create(np.zeros((0, 3)), np.zeros((0, 3))),
        lambda c, tg: jp.targets.Boxes.create([[0, 0, 0]], [[1.0, -0.5, 1.0]]),
        lambda c, tg: jp.targets.Mesh.create(np.zeros((3, 3)), np.zeros((0, 3), int)),
        lambda c, tg: jp.Camera.from_fov(10, 10, 4.0),
    ],
)
def test_bad_input_raises_value_error(camera, make):
    with pytest.raises(ValueError):
        make(camera, jp.targets.n1())


def test_cloud_from_points_contract():
    c = jp.Cloud.from_points(np.ones((5, 3)))
    assert c.points.shape == (5, 3) and int(c.num_valid) == 5
    masked = jp.Cloud.from_points(np.array([[1.0, 2, 3], [np.nan, 0, 0]]), valid=np.array([True, False]))
    assert masked.compact().shape == (1, 3)
    for bad in (np.ones((5, 2)), np.array([[np.nan, 0, 0]]), np.array([["a", "b", "c"]])):
        with pytest.raises(ValueError):
            jp.Cloud.from_points(bad)


@pytest.mark.parametrize("name", ["n5", "fragment"])
def test_a_scaled_target_is_the_same_shape_times_the_factor(name):
    """`targets.scaled` multiplies every triangle vertex by the factor (boxes and meshes), and
    refuses a factor that is not positive."""
    target = getattr(jp.targets, name)()
    big = jp.targets.scaled(target, 3.0)
    assert type(big) is type(target)

    def triangles(t):
        return np.asarray(t.triangles() if isinstance(t, jp.targets.Boxes) else t.triangles)

    np.testing.assert_allclose(triangles(big), 3.0 * triangles(target), rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="factor"):
        jp.targets.scaled(target, 0.0)
