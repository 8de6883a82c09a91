"""Same capture results in two checkouts: the capture benchmark's first pair of each target,
noise level and bin (`capture.make_cases(pairs)`, 30 pairs at `pairs=1`) through
`jp.estimate(prev, curr, Config.capture())` sized per pair, as `capture_benchmark.py` runs
it; each row's outcome, status, rotation and centroid errors and warm time. Run it in each
checkout on one machine and compare the files: a change meant to leave the CPU path alone
gives identical rows (the times aside).

    uv run python experiments/capture_equivalence.py OUT.json [pairs]
    uv run python experiments/capture_equivalence.py --compare A.json B.json
"""

from __future__ import annotations

import json
import statistics
import sys

FIELDS = ("found", "status", "rotation_error_deg", "centroid_error_cm")


def run(out: str, pairs: int = 1) -> None:
    import jaxpose as jp
    from jaxpose.evaluation import capture
    from jaxpose.evaluation.bench import machine

    cases, _ = capture.make_cases(pairs)
    rows, first_calls = capture.run_jaxpose(cases, jp.Config.capture())
    keep = ("target", "sigma_cm", "bin", "motion_deg", *FIELDS, "seconds")
    payload = {"machine": machine(), "first_calls_s": first_calls, "rows": [{k: r[k] for k in keep} for r in rows]}
    with open(out, "w") as f:
        json.dump(payload, f, indent=1)
    print(f"wrote {out}: {len(rows)} pairs, {sum(r['found'] for r in rows)} found")


def compare(a: str, b: str) -> None:
    rows_a, rows_b = (json.load(open(path))["rows"] for path in (a, b))
    identical = 0
    for x, y in zip(rows_a, rows_b, strict=True):
        if all(x[k] == y[k] for k in FIELDS):
            identical += 1
        else:
            print("differs:", {k: (x[k], y[k]) for k in ("target", "sigma_cm", "bin", *FIELDS)})
    times = [statistics.median(r["seconds"] for r in rows) for rows in (rows_a, rows_b)]
    print(f"identical rows: {identical} of {len(rows_a)}; median s per pair {times[0]:.3f} / {times[1]:.3f}")


if __name__ == "__main__":
    if sys.argv[1] == "--compare":
        compare(sys.argv[2], sys.argv[3])
    else:
        run(sys.argv[1], *(int(a) for a in sys.argv[2:]))
