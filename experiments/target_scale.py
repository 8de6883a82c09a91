"""Targets of other sizes: the realistic benchmark's draw with every target scaled (issue 21).

The realistic benchmark's targets are 0.6–4 m across, seen from 2–6.5 m. Here each of N5,
the satellite, the upper stage and the fragment is scaled by s (0.3: a 0.6 m box, a 1.1 m
satellite; 3: a 6 m box, an 11 m satellite, an 8 m upper stage) and drawn as in
`jaxpose.evaluation.realistic.draw_pair`, with the distances and the shift that follow the
size: the target from `nearest_distance` (where 80 % of its extent fills the 40° field, at
least 2 m) to max(6.5 m, 1.4 × that), a random attitude, a turn of 1–15° about a random axis
and a shift of up to 5·s cm; the CamCube's 204 × 204 pixels, its range gate opened to 3× the
farthest distance; ToF range noise σ at 5 m, growing with range (at 15 m, three times σ),
0–30 % dropout, flying pixels where σ > 0.

Each pair runs `jp.estimate(prev, curr, config, key=...)` with the default config but for
`Patterns.cell_steps` (the cell is the larger of 2.6 cm and that many sampling steps of the
previous cloud):

- `steps_1.25`: 1.25;
- `steps_1.5`: 1.5;
- `fixed_cell`: 0, the cell 2.6 cm whatever the data;

and small_gicp's GICP on the same clouds (as in the realistic benchmark). The variants carry
`cell_steps` as an array, so that they share one compiled program per capacity bucket.
Reported per scale and noise level: found (< 1° and < 5 cm), successes, false successes
(success but not found), refusals of a found result (status low score while found), median
errors; per pair the sampling step and the cell used.

    uv run --extra peers python experiments/target_scale.py [pairs] [scales] [levels] [name]
        → results/<name>.{json,md}   (defaults: 3, 0.3,2,3, 0,1, target_scale)
"""

from __future__ import annotations

import math
import statistics
import sys

import jax
import jax.numpy as jnp
import numpy as np
from _common import RESULTS, write_json

import jaxpose as jp
from jaxpose._estimate import STATUS_NAME, SUCCESS
from jaxpose._neighbours import voxel_spacing
from jaxpose._problem import cell_size
from jaxpose.evaluation import realistic
from jaxpose.evaluation.realistic import SIMULATE, Case, _axis_angle, _random_rotation, errors, gicp, traced_camera
from jaxpose.sim import targets

TARGETS = ("n5", "satellite", "upper_stage", "fragment")
CELL_STEPS = {"steps_1.25": 1.25, "steps_1.5": 1.5, "fixed_cell": 0.0}
"""The variants: `Patterns.cell_steps` of each."""
VARIANTS = {name: jp.Config(patterns=jp.Patterns(cell_steps=jnp.asarray(steps))) for name, steps in CELL_STEPS.items()}


def draw(name: str, s: float, sigma: float, i: int) -> Case:
    """One pair of `name` scaled by s at range noise σ (cm), from its own seed."""
    target = targets.scaled(getattr(targets, name)(), s)
    near = realistic.nearest_distance(target)
    far = max(6.5, 1.4 * near)
    rng = np.random.default_rng([11, TARGETS.index(name), round(100 * s), round(10 * sigma), i])
    R0 = _random_rotation(rng)
    t0 = np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(near, far)])
    angle = math.radians(rng.uniform(1.0, 15.0))
    dR = _axis_angle(rng.normal(size=3), angle)
    shift = rng.normal(size=3)
    shift *= 0.05 * s * rng.uniform() ** (1 / 3) / np.linalg.norm(shift)
    R1, t1 = dR @ R0, t0 + shift
    camera = traced_camera(
        jp.Camera.camcube2(
            noise_sigma=sigma / 100,
            noise_range_ref=realistic.RANGE_REF,
            dropout=float(rng.uniform(0.0, 0.3)),
            flying=0.5 if sigma > 0 else 0.0,
            range_max=3 * far,
        )
    )
    keys = jax.random.split(jax.random.key(int(rng.integers(2**31))))
    prev = SIMULATE(camera, target, jnp.asarray(R0), jnp.asarray(t0), keys[0])
    curr = SIMULATE(camera, target, jnp.asarray(R1), jnp.asarray(t1), keys[1])
    return Case(name, sigma, i, prev, curr, R1 @ R0.T, t1 - R1 @ R0.T @ t0, math.degrees(angle))


def run_pair(case: Case, s: float) -> dict:
    pts, valid = jnp.asarray(case.prev.points), jnp.asarray(case.prev.valid)
    row = {
        "target": case.target,
        "scale": s,
        "sigma_cm": case.sigma_cm,
        "pair": case.index,
        "points": int(valid.sum()),
        "step_cm": 100 * float(voxel_spacing(pts.T, valid)),
        "motion_deg": case.motion_deg,
    }
    for name, config in VARIANTS.items():
        row[f"{name}_cell_cm"] = 100 * float(cell_size(pts, valid, config))
        try:
            est = jp.estimate(case.prev, case.curr, config, key=jax.random.key(case.index))
            status = int(est.status)
            row[name] = {**errors(case, est.rotation, est.translation), "status": STATUS_NAME[status]}
        except ValueError as err:
            row[name] = {"found": False, "status": f"refused: {err}"}
    R, t = gicp(np.asarray(case.prev.compact()), np.asarray(case.curr.compact()))
    row["GICP"] = errors(case, R, t)
    return row


def summary(rows: list[dict]) -> list[dict]:
    out = []
    keys = sorted({(r["scale"], r["sigma_cm"]) for r in rows})
    for scale, sigma in [*keys, ("all", "all")]:
        sel = [r for r in rows if scale == "all" or (r["scale"] == scale and r["sigma_cm"] == sigma)]
        entry = {"scale": scale, "sigma_cm": sigma, "pairs": len(sel)}
        for name in [*VARIANTS, "GICP"]:
            res = [r[name] for r in sel]
            success = [x for x in res if x.get("status") == STATUS_NAME[SUCCESS]]
            entry[name] = {
                "found": sum(x["found"] for x in res),
                "rotation_median_deg": statistics.median(x.get("rotation_error_deg", math.inf) for x in res),
                "centroid_median_cm": statistics.median(x.get("centroid_error_cm", math.inf) for x in res),
            }
            if name != "GICP":
                entry[name] |= {
                    "successes": len(success),
                    "false_successes": sum(not x["found"] for x in success),
                    "found_but_low_score": sum(x["found"] and x["status"] == "low score" for x in res),
                }
        out.append(entry)
    return out


def markdown(summ: list[dict], command: str) -> str:
    head = (
        f"`{command}`. Each variant: found / successes / false successes / found but low score / median "
        "rotation ° / median centroid cm; GICP: found / median rotation ° / median centroid cm.\n\n"
        "| scale | σ, cm | pairs | "
        + " | ".join(f"cell_steps {steps:g}" for steps in CELL_STEPS.values())
        + " | GICP |\n|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for e in summ:
        cells = []
        for name in VARIANTS:
            v = e[name]
            cells.append(
                f"{v['found']} / {v['successes']} / {v['false_successes']} / {v['found_but_low_score']} / "
                f"{v['rotation_median_deg']:.3f} / {v['centroid_median_cm']:.3f}"
            )
        g = e["GICP"]
        cells.append(f"{g['found']} / {g['rotation_median_deg']:.3f} / {g['centroid_median_cm']:.3f}")
        lines.append(f"| {e['scale']} | {e['sigma_cm']} | {e['pairs']} | " + " | ".join(cells) + " |")
    return head + "\n".join(lines) + "\n"


def main():
    pairs = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    scales = tuple(float(x) for x in sys.argv[2].split(",")) if len(sys.argv) > 2 else (0.3, 2.0, 3.0)
    levels = tuple(float(x) for x in sys.argv[3].split(",")) if len(sys.argv) > 3 else (0.0, 1.0)
    out_name = sys.argv[4] if len(sys.argv) > 4 else "target_scale"
    command = "uv run --extra peers python experiments/target_scale.py " + " ".join(sys.argv[1:])
    rows = []
    for s in scales:
        for name in TARGETS:
            for sigma in levels:
                for i in range(pairs):
                    row = run_pair(draw(name, s, sigma, i), s)
                    rows.append(row)
                    print(
                        f"{name} ×{s:g} σ{sigma:g} #{i}: step {row['step_cm']:.2f} cm, cell "
                        f"{row['steps_1.25_cell_cm']:.2f} / {row['steps_1.5_cell_cm']:.2f} cm | "
                        + " | ".join(
                            f"{v} {row[v].get('rotation_error_deg', math.nan):.3f}° "
                            f"{row[v].get('centroid_error_cm', math.nan):.2f} cm {row[v]['status']}"
                            for v in VARIANTS
                        )
                        + f" | GICP {row['GICP']['rotation_error_deg']:.3f}° {row['GICP']['centroid_error_cm']:.2f} cm",
                        flush=True,
                    )
    summ = summary(rows)
    write_json(f"{out_name}.json", {"command": command, "summary": summ, "rows": rows})
    (RESULTS / f"{out_name}.md").write_text(markdown(summ, command))
    print(markdown(summ, command))


if __name__ == "__main__":
    main()
