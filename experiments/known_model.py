"""Known-model baseline (issue 7): fit the true box model to each cloud by Levenberg–Marquardt
(`jaxpose.model_fit`) and compare the motion with the truth, on the paper's four pairs.

Each fit starts from the true pose perturbed by `offset_deg` about a random axis and
`offset_cm` in a random direction (the model-free method needs no start). Errors as in
`jaxpose.comparison` (rotation angle, largest abs error of p in frame n).

    uv run python experiments/known_model.py  →  results/known_model.json
"""

import math
import time

import jax
import jaxlie
import numpy as np
from _common import write_json

import jaxpose as jp
from jaxpose._poses import relative_motion
from jaxpose.evaluation.comparison import pair_errors
from jaxpose.evaluation.model_fit import fit_model
from jaxpose.sim import paper_pairs

OFFSETS = ((2.0, 2.0), (5.0, 5.0), (10.0, 10.0), (20.0, 20.0))
TRIALS = 5


def perturbed(key, R, t, deg, cm):
    k1, k2 = jax.random.split(key)
    axis, shift = jax.random.normal(k1, (3,)), jax.random.normal(k2, (3,))
    dR = jaxlie.SO3.exp(axis / np.linalg.norm(axis) * math.radians(deg)).as_matrix()
    return dR @ R, t + shift / np.linalg.norm(shift) * cm / 100


def main():
    rows = []
    for pair in paper_pairs():
        model = getattr(jp.targets, pair.label.split()[0].lower())()
        for deg, cm in OFFSETS:
            for trial in range(TRIALS):
                key = jax.random.key(1000 * trial + int(deg))
                k1, k2 = jax.random.split(key)
                t0 = time.perf_counter()
                f1 = fit_model(pair.prev, model, *perturbed(k1, pair.R1, pair.t1, deg, cm))
                f2 = fit_model(pair.curr, model, *perturbed(k2, pair.R2, pair.t2, deg, cm))
                R, t = relative_motion(f1.rotation, f1.translation, f2.rotation, f2.translation)
                seconds = time.perf_counter() - t0
                err = pair_errors(pair, R, t)
                rows.append({"pair": pair.label, "offset_deg": deg, "offset_cm": cm, "trial": trial, **err,
                             "rms_mm": 1e3 * max(float(f1.rms), float(f2.rms)), "seconds": seconds})  # fmt: skip
        print(pair.label, flush=True)
    summary = {}
    for deg, cm in OFFSETS:
        sel = [r for r in rows if r["offset_deg"] == deg]
        good = [r for r in sel if r["rotation_error_deg"] < 1.0]
        summary[f"{deg:g} deg / {cm:g} cm"] = {
            "found": f"{len(good)}/{len(sel)}",
            "max_angle_error_deg_found": max((r["angle_error_deg"] for r in good), default=None),
            "max_translation_error_cm_found": max((r["translation_error_cm"] for r in good), default=None),
            "median_seconds_pair": float(np.median([r["seconds"] for r in sel])),
        }
    print(summary)
    write_json("known_model.json", {"offsets": OFFSETS, "trials": TRIALS, "summary": summary, "rows": rows})


if __name__ == "__main__":
    main()
