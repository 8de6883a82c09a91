"""Why the tracking benchmark's upper stage at 1 cm (tumble 53, 7.9 °/s, a third draw) is lost
from its first frame (issue 25).

From the saved registrations of the run at 404dc03
(`results/tracking_benchmark_default_404dc03_from40_chains.npz`): the frame of the first
registration and the motion from frame 0 by then. Then, for the first frames, the tracker's own
estimate against frame 0 (its registration config, the capacities of the whole sequence, the
guess at rest, the key of `jp.track`): its status and each distinct hypothesis's angle from
rest and from the truth. Motion continuity resolves an ambiguous estimate against the
prediction, which is rest until a frame registers; a hypothesis counts as clearly nearest when
it lies within `CONTINUITY_FRACTION` × `Thresholds.ambiguous_deg` of it.

    uv run python experiments/track_start.py [frames] → results/track_start.{json,md}
        (default frames: 1,2,3,5,10)
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np
import tracking_benchmark as tb
from _common import RESULTS, write_json

import jaxpose as jp
from jaxpose._estimate import STATUS_NAME, estimate_problem
from jaxpose._problem import sized_sequence_config
from jaxpose.tracking._track import CONTINUITY_FRACTION, default_tracking_config, is_registered, registration_config

TUMBLE, SAVED_RUN, ROW = 53, "tracking_benchmark_default_404dc03_from40", 13


def degrees(R, Q) -> float:
    return float(np.degrees(jp.rotation_angle(jnp.asarray(R), jnp.asarray(Q))))


def main(frames=(1, 2, 3, 5, 10)) -> None:
    saved = np.load(RESULTS / f"{SAVED_RUN}_chains.npz")
    truth = saved["truth"][ROW]
    registered = np.asarray(is_registered(jnp.asarray(saved["status"][ROW]), jnp.asarray(saved["continuity"][ROW])))
    first = int(np.argmax(registered[1:])) + 1
    family, sigma, tumble, key = tb.draw_tumble(TUMBLE, tb.BENCHMARK_SEEDS)
    clouds = tb.simulate_tumble(family, sigma, tumble, key, 10.0, 25.0).clouds.floating()
    config = registration_config(sized_sequence_config(clouds, default_tracking_config()))
    frame0 = jax.tree.map(lambda x: x[0], clouds)
    rows = []
    for k in frames:
        problem = jp.Problem.build(frame0, jax.tree.map(lambda x, k=k: x[k], clouds), config)
        est = estimate_problem(problem, config, jax.random.fold_in(jax.random.fold_in(key, 2), k), jnp.zeros(6))
        motion = truth[k] @ truth[0].T
        H = est.hypotheses
        hyps = [
            {"from_rest_deg": degrees(H.rotation[j], np.eye(3)), "error_deg": degrees(H.rotation[j], motion)}
            for j in range(H.score.shape[0])
            if bool(H.distinct[j])
        ]
        status = STATUS_NAME[int(est.status)]
        rows.append({"frame": k, "motion_deg": degrees(motion, np.eye(3)), "status": status, "hypotheses": hyps})
    gate = CONTINUITY_FRACTION * float(config.thresholds.ambiguous_deg)
    rate = np.degrees(np.linalg.norm(np.asarray(tumble.rate)))
    then = degrees(truth[first] @ truth[0].T, np.eye(3))
    report = {"tumble": TUMBLE, "first_registered": first, "motion_then_deg": then, "gate_deg": gate, "frames": rows}
    write_json("track_start.json", report)
    lines = [
        f"Tumble {TUMBLE} ({family}, σ {sigma:g} cm, {rate:.1f} °/s): first registered "
        f"frame {first}, {report['motion_then_deg']:.1f}° from frame 0; continuity's fixed gate {gate:.2f}°.\n",
        "| frame | motion from frame 0, ° | status | hypotheses: from rest / from the truth, ° |",
        "|---|---|---|---|",
    ]
    lines += [
        f"| {r['frame']} | {r['motion_deg']:.2f} | {r['status']} | "
        + "; ".join(f"{h['from_rest_deg']:.2f} / {h['error_deg']:.2f}" for h in r["hypotheses"])
        + " |"
        for r in rows
    ]
    (RESULTS / "track_start.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(*(tuple(int(x) for x in a.split(",")) for a in sys.argv[1:2]))
