"""The realistic benchmark: every built-in target, random views, a ToF sensor's noise, and the
peers on the same clouds in the same run (`jaxpose benchmark`).

Each pair (ours, fixed by `seed`):

- target: one of [`jaxpose.targets.BUILT_IN`][] (the mesh `debris` is loaded from its file);
- previous pose: a uniformly random attitude, the target's centre at a distance drawn
  uniformly from [`near`, 6.5 m] on the optical axis, `near` = max(2 m, the distance at
  which 80 % of its largest extent fills the 40° field), offset laterally by up to 0.2 m;
- motion: a rotation of 1–15° about a uniformly random axis through the target's centre,
  and a translation drawn uniformly from a 5 cm ball;
- sensor ([`jaxpose.Camera.camcube2`][]): range noise σ ∈ `LEVELS_CM` head-on at 5 m,
  growing with range and with the angle of incidence (`noise_range_ref` = 5 m), dropout
  drawn uniformly from 0–30 %, and, when σ > 0, flying pixels at depth edges with
  probability 0.5.

Errors, in the camera frame c: the rotation error is the angle of R_est R_trueᵀ (degrees),
the centroid error is |R_est c + t_est − (R_true c + t_true)| with c the centroid of the
previous cloud (centimetres). A pair is found when the rotation error is below `FOUND_DEG`
and the centroid error below `FOUND_CM`; a false success is a jaxpose status "success"
that is not found. Times: jaxpose's public `estimate` after a warm-up call of the same
capacity bucket (compilation reported apart); peers with their preprocessing.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._cloud import Cloud
from .._rotations import rotation_angle
from .._uncertainty import rotation_std
from ..sim import targets
from ..sim._camera import Camera
from ..sim._simulate import simulate
from .comparison import FOUND_DEG, outcome_counts

LEVELS_CM = (0.0, 0.5, 1.0, 2.0)
"""Range noise σ of the benchmark, head-on at 5 m, centimetres."""

FOUND_CM = 5.0
"""A result within `FOUND_DEG` and this centroid error (centimetres) counts as found."""

RANGE_REF = 5.0

SIMULATE = eqx.filter_jit(simulate)
"""[`jaxpose.simulate`][], jitted once for every draw of this module and of
`jaxpose.evaluation.capture` (with `traced_camera`, one program per camera size and target)."""


def traced_camera(camera: Camera) -> Camera:
    """The camera with its float fields as arrays. `eqx.filter_jit` takes a Python float as a
    static argument, so each drawn dropout and noise level would compile `simulate` again
    (≈ 0.8 s and thousands of memory mappings per pair on the 2-core CPU); as arrays they are
    traced, and one program simulates every pair of a target. The clouds are the same."""
    return jax.tree.map(jnp.asarray, camera)


@dataclass(frozen=True)
class Case:
    """One benchmark pair: the clouds and the true motion x ↦ R x + t (camera frame c)."""

    target: str
    sigma_cm: float
    index: int
    prev: Cloud
    curr: Cloud
    rotation: np.ndarray
    translation: np.ndarray
    motion_deg: float

    @property
    def label(self) -> str:
        return self.label_of(self.target, self.sigma_cm, self.index)

    @staticmethod
    def label_of(target: str, sigma_cm: float, index: int) -> str:
        """A pair's label: target, σ in cm and index, e.g. "n5 σ0.5 #3"."""
        return f"{target} σ{sigma_cm:g} #{index}"


def _extent(target) -> float:
    tris = target.triangles() if isinstance(target, targets.Boxes) else target.triangles
    pts = np.asarray(tris).reshape(-1, 3)
    return float(np.max(np.ptp(pts, axis=0)))


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    k = axis / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


class Drawn(NamedTuple):
    """One simulated pair of `draw_pair`: the clouds, the true motion x ↦ R x + t and the
    previous pose (R0, t0), camera frame, and the turn's angle (radians)."""

    prev: Cloud
    curr: Cloud
    rotation: np.ndarray
    translation: np.ndarray
    angle: float
    prev_rotation: np.ndarray
    prev_translation: np.ndarray


def draw_pair(sim, target, near: float, sigma: float, rng: np.random.Generator, low_deg: float, high_deg: float):
    """A pair as the module docstring describes, with a turn drawn uniformly from
    [`low_deg`, `high_deg`] degrees; `sim` is (a jitted) `simulate`, σ in centimetres."""
    R0 = _random_rotation(rng)
    t0 = np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(near, 6.5)])
    angle = math.radians(rng.uniform(low_deg, high_deg))
    dR = _axis_angle(rng.normal(size=3), angle)
    shift = rng.normal(size=3)
    shift *= 0.05 * rng.uniform() ** (1 / 3) / np.linalg.norm(shift)
    R1, t1 = dR @ R0, t0 + shift
    camera = traced_camera(
        Camera.camcube2(
            noise_sigma=sigma / 100,
            noise_range_ref=RANGE_REF,
            dropout=float(rng.uniform(0.0, 0.3)),
            flying=0.5 if sigma > 0 else 0.0,
        )
    )
    keys = jax.random.split(jax.random.key(int(rng.integers(2**31))))
    prev = sim(camera, target, jnp.asarray(R0), jnp.asarray(t0), keys[0])
    curr = sim(camera, target, jnp.asarray(R1), jnp.asarray(t1), keys[1])
    return Drawn(prev, curr, R1 @ R0.T, t1 - R1 @ R0.T @ t0, angle, R0, t0)


def nearest_distance(target) -> float:
    """The benchmark's nearest distance for a target (metres): 2 m, or where 80 % of its
    largest extent fills the 40° field."""
    return max(2.0, 0.8 * _extent(target) / 2 / math.tan(math.radians(20.0)))


def make_cases(
    pairs: int = 8, seed: int = 0, names=targets.BUILT_IN, levels=LEVELS_CM, keep: Callable[[str], bool] | None = None
) -> list[Case]:
    """`pairs` pairs for every target and noise level (see the module docstring). `keep`: only
    the pairs whose label (`Case.label`, e.g. "n5 σ0.5 #3") it accepts are simulated; each
    pair is drawn from its own seed (`seed`, the target's position in `names`, the level's
    position in `levels`, index), so a kept pair is the same as in the whole set, whereas a
    shorter `names` or `levels` draws other pairs under the same labels."""
    cases = []
    for ti, name in enumerate(names):
        target = getattr(targets, name)()
        near = nearest_distance(target)
        for li, sigma in enumerate(levels):
            for i in range(pairs):
                if keep is not None and not keep(Case.label_of(name, sigma, i)):
                    continue
                d = draw_pair(SIMULATE, target, near, sigma, np.random.default_rng([seed, ti, li, i]), 1.0, 15.0)
                cases.append(Case(name, sigma, i, d.prev, d.curr, d.rotation, d.translation, math.degrees(d.angle)))
    return cases


def errors(case: Case, R, t) -> dict:
    """Rotation error (degrees) and centroid error (centimetres) of an estimated motion."""
    R, t = np.asarray(R, float), np.asarray(t, float)
    c = case.prev.compact().astype(float).mean(axis=0)
    moved_est, moved_true = R @ c + t, case.rotation @ c + case.translation
    rot = math.degrees(float(rotation_angle(R, case.rotation)))
    cen = 100 * float(np.linalg.norm(moved_est - moved_true))
    return {"rotation_error_deg": rot, "centroid_error_cm": cen, "found": rot < FOUND_DEG and cen < FOUND_CM}


def _row(case: Case, method: str, **kw) -> dict:
    return {"target": case.target, "sigma_cm": case.sigma_cm, "pair": case.index, "method": method, **kw}


def warm_estimates(cases: list[Case], config, seed: int, first_calls: dict):
    """The public `jaxpose.estimate` on each case (key = (seed, i)), yielding (case, estimate,
    seconds), or (case, the ValueError, None) for a refused pair. Pairs of one capacity bucket
    run together, so that each bucket compiles once however few programs stay in memory. The
    first call of each bucket is repeated so that its time is warm; that first time
    (compilation included) goes into `first_calls`, keyed by the bucket."""
    from .._config import Config
    from .._estimate import estimate
    from .._problem import sized_config

    buckets = [_bucket(sized_config(c.prev, c.curr, config or Config())) for c in cases]
    for i in sorted(range(len(cases)), key=lambda i: buckets[i]):
        case, bucket = cases[i], buckets[i]
        key = jax.random.fold_in(jax.random.key(seed), i)
        try:
            t0 = time.perf_counter()
            est = jax.block_until_ready(estimate(case.prev, case.curr, config, key=key))
            seconds = time.perf_counter() - t0
        except ValueError as err:
            yield case, err, None
            continue
        if bucket not in first_calls:
            first_calls[bucket] = seconds
            t0 = time.perf_counter()
            est = jax.block_until_ready(estimate(case.prev, case.curr, config, key=key))
            seconds = time.perf_counter() - t0
        yield case, est, seconds


def run_jaxpose(cases: list[Case], config=None, seed: int = 0, progress: Callable[[], None] | None = None):
    """The public `jaxpose.estimate` on each case ([`warm_estimates`][]). Returns the rows and,
    per capacity bucket met, the first call's time (compilation included)."""
    from .._estimate import STATUS_NAME

    rows, first_calls = [], {}
    for case, est, seconds in warm_estimates(cases, config, seed, first_calls):
        if isinstance(est, ValueError):
            rows.append(_row(case, "jaxpose", refused=str(est)))
            continue
        rows.append(
            _row(
                case,
                "jaxpose",
                **errors(case, est.rotation, est.translation),
                seconds=seconds,
                status=STATUS_NAME[int(est.status)],
                rotation_std_deg=_rotation_std_deg(est),
                spread_deg=math.degrees(float(est.spread)),
            )
        )
        if progress is not None:
            progress()
    return rows, first_calls


def _rotation_std_deg(est) -> float | None:
    """The estimate's largest predicted rotation standard deviation (degrees), or None
    without a covariance."""
    if est.covariance is None:
        return None
    return math.degrees(float(rotation_std(est.covariance)))


def _bucket(config) -> tuple[int, int, int, int]:
    c = config.capacities
    return (c.max_points, c.max_prev_points, c.grid_cells, c.max_cells)


def gicp(prev: np.ndarray, curr: np.ndarray, start: tuple[np.ndarray, np.ndarray] | None = None):
    """small_gicp's GICP as a new user would call it: 5 mm voxels, 0.3 m correspondences, one
    thread, from the identity, or from `start`, a motion (R, t) in the camera frame (metres),
    x ↦ R x + t (e.g. the true one, to find where GICP's own cost is least)."""
    import small_gicp

    init = np.eye(4)
    if start is not None:
        init[:3, :3], init[:3, 3] = np.asarray(start[0], float), np.asarray(start[1], float)
    result = small_gicp.align(
        np.asarray(curr, np.float64),
        np.asarray(prev, np.float64),
        init_T_target_source=init,
        registration_type="GICP",
        downsampling_resolution=0.005,
        max_correspondence_distance=0.3,
        num_threads=1,
    )
    T = np.asarray(result.T_target_source)
    return T[:3, :3], T[:3, 3]


def open3d_plane_icp(prev: np.ndarray, curr: np.ndarray):
    """Open3D's point-to-plane ICP: normals from 20 neighbours within 8 cm, 0.3 m
    correspondences, 50 iterations, from the identity."""
    import open3d as o3d

    reg = o3d.pipelines.registration

    def cloud(points):
        c = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
        c.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.08, max_nn=20))
        return c

    criteria = reg.ICPConvergenceCriteria(max_iteration=50)
    method = reg.TransformationEstimationPointToPlane()
    T = np.asarray(reg.registration_icp(cloud(prev), cloud(curr), 0.3, np.eye(4), method, criteria).transformation)
    return T[:3, :3], T[:3, 3]


PEERS = {"small_gicp GICP": ("small_gicp", gicp), "Open3D point-to-plane ICP": ("open3d", open3d_plane_icp)}
"""The peers of the benchmark: name → (the module it needs, the aligner)."""


def timed_align(align, case: Case) -> tuple[np.ndarray, np.ndarray, float]:
    """A peer's motion (R, t) on a case's valid points, and the seconds it took."""
    prev, curr = case.prev.compact().astype(float), case.curr.compact().astype(float)
    t0 = time.perf_counter()
    R, t = align(prev, curr)
    return R, t, time.perf_counter() - t0


def run_peer(name: str, align, cases: list[Case], progress: Callable[[], None] | None = None) -> list[dict]:
    rows = []
    for case in cases:
        R, t, seconds = timed_align(align, case)
        rows.append(_row(case, name, **errors(case, R, t), seconds=seconds))
        if progress is not None:
            progress()
    return rows


def _quantile(values, q) -> float:
    return float(np.quantile(np.asarray(values, float), q)) if values else math.nan


def _found_and_false(done: list[dict]) -> dict[str, int]:
    counts = outcome_counts([r["found"] for r in done], [r.get("status") == "success" for r in done])
    return {"found": counts["found"], "false_success": counts["false_success"]}


def summarise(rows: list[dict], by=("sigma_cm",)) -> list[dict]:
    """One summary per method and group (`by`: "sigma_cm", "target" or both): pairs,
    refused, found, false successes, median and 90th-percentile errors, median time."""
    groups = {}
    for r in rows:
        groups.setdefault((r["method"], *(r[k] for k in by)), []).append(r)
    out = []
    for key, rs in groups.items():
        done = [r for r in rs if "refused" not in r]
        rot = [r["rotation_error_deg"] for r in done]
        cen = [r["centroid_error_cm"] for r in done]
        out.append(
            {
                "method": key[0],
                **dict(zip(by, key[1:], strict=True)),
                "pairs": len(rs),
                "refused": len(rs) - len(done),
                **_found_and_false(done),
                "median_rotation_deg": _quantile(rot, 0.5),
                "p90_rotation_deg": _quantile(rot, 0.9),
                "median_centroid_cm": _quantile(cen, 0.5),
                "p90_centroid_cm": _quantile(cen, 0.9),
                "median_ms": 1e3 * statistics.median(r["seconds"] for r in done) if done else math.nan,
            }
        )
    return out


def markdown(summary: list[dict], by=("sigma_cm",)) -> str:
    """The summary as a Markdown table."""
    head = [k for k in by] + [
        "method",
        "found",
        "refused",
        "false success",
        "rotation median / p90, °",
        "centroid median / p90, cm",
        "median ms",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for s in summary:
        cells = [f"{s[k]:g}" if isinstance(s[k], float) else str(s[k]) for k in by]
        cells += [
            s["method"],
            f"{s['found']}/{s['pairs']}",
            str(s["refused"]),
            str(s["false_success"]) if s["method"].startswith("jaxpose") else "–",
            f"{s['median_rotation_deg']:.4f} / {s['p90_rotation_deg']:.4f}",
            f"{s['median_centroid_cm']:.4f} / {s['p90_centroid_cm']:.4f}",
            f"{s['median_ms']:.1f}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def available_peers() -> tuple[dict, dict]:
    """The benchmark's peers that import here, and for the others the import error."""
    found, missing = {}, {}
    for name, (module, align) in PEERS.items():
        try:
            __import__(module)
            found[name] = align
        except (ImportError, OSError) as err:  # Open3D raises ImportError for a missing libusb
            missing[name] = f"{type(err).__name__}: {err}"
    return found, missing


def plot(summary: list[dict], path) -> None:
    """Median rotation and centroid errors against the noise level, one line per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for method in dict.fromkeys(s["method"] for s in summary):
        mine = sorted((s for s in summary if s["method"] == method), key=lambda s: s["sigma_cm"])
        sig = [s["sigma_cm"] for s in mine]
        axes[0].plot(sig, [s["median_rotation_deg"] for s in mine], "o-", label=method)
        axes[1].plot(sig, [s["median_centroid_cm"] for s in mine], "o-", label=method)
    for ax, label in zip(axes, ("median rotation error, °", "median centroid error, cm"), strict=True):
        ax.set_xlabel("range noise σ at 5 m, cm")
        ax.set_ylabel(label)
        ax.set_yscale("log")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_report(
    stem, header: str, rows: list[dict], first_calls: dict, missing: dict, head: dict, with_plot: bool = False
) -> str:
    """The benchmark's report of `rows` (`run_jaxpose` and `run_peer`): `header` (one
    sentence: the config and the pairs), the tables by noise level and by target and noise
    level, the first call of each capacity bucket and the peers that did not run. Writes it to
    `stem`.md, and to `stem`.json with `head` (the machine, the pairs, the settings) first,
    then the summaries, the first calls, the missing peers and every row; with `with_plot`,
    the plot by noise level to `stem`.png. Returns the text."""
    import json
    from pathlib import Path

    stem = Path(stem)
    by_noise, by_target = summarise(rows, ("sigma_cm",)), summarise(rows, ("target", "sigma_cm"))
    text = f"{header}\n\n## By noise level\n\n" + markdown(by_noise) + "\n\n## By target and noise level\n\n"
    text += markdown(by_target, ("target", "sigma_cm"))
    firsts = ", ".join(f"{s:.1f} s" for s in first_calls.values())
    text += f"\n\njaxpose first call per capacity bucket (compilation included, not in the times above): {firsts}."
    if missing:
        text += "\n\nNot run here: " + "; ".join(f"{k} ({v})" for k, v in missing.items())
    stem.parent.mkdir(parents=True, exist_ok=True)
    stem.with_suffix(".md").write_text(text + "\n")
    if with_plot:
        plot(by_noise, stem.with_suffix(".png"))
    payload = {**head, "by_noise": by_noise, "by_target": by_target}
    payload |= {"first_calls_s": list(first_calls.values()), "missing": missing, "rows": rows}
    stem.with_suffix(".json").write_text(json.dumps(payload, indent=2, default=float))
    return text


__all__ = [
    "FOUND_CM",
    "LEVELS_CM",
    "PEERS",
    "Case",
    "errors",
    "make_cases",
    "markdown",
    "run_jaxpose",
    "run_peer",
    "summarise",
    "write_report",
]
