"""What changed between two runs of `fine_draws.py` on the same draws: counts and changed pairs.

    uv run python experiments/draw_changes.py BASE NEW [VARIANT]
        → results/draw_changes_<NEW>.{json,md}

BASE and NEW name `results/<name>.json` files written by `fine_draws.py --out` with the same
`--levels`, `--seeds` and `--pairs` (the same pairs in the same order, which is checked);
VARIANT is the variant's name in both (default "default"). Per noise level: pairs found (< 1°
and < 5 cm), successes, false successes (a success not found) and `ambiguous` estimates,
before and after; then every pair whose status changed or whose rotation error moved by more
than 0.001°, with its status and rotation error before and after. A change of the status
rules alone moves statuses and leaves every error where it was.
"""

from __future__ import annotations

import json
import sys

from _common import RESULTS, write_json

from jaxpose._estimate import AMBIGUOUS, STATUS_NAME, SUCCESS

MOVED_DEG = 1e-3
"""A rotation error that moved by more than this (degrees) marks the pair as changed."""


def load(name: str, variant: str) -> dict[str, list[tuple[str, dict]]]:
    """(pair label, row) of every pair of `variant`, per noise level, from `results/<name>.json`."""
    levels = json.loads((RESULTS / f"{name}.json").read_text())["levels"]
    return {level: list(zip(v["pairs"], v["rows"][variant], strict=True)) for level, v in levels.items()}


def counts(rows: list[tuple[str, dict]]) -> dict[str, int]:
    """Found, successes, false successes and ambiguous estimates among `rows`."""
    return {
        "found": sum(r["found"] for _, r in rows),
        "success": sum(r["status"] == SUCCESS for _, r in rows),
        "false_success": sum(r["status"] == SUCCESS and not r["found"] for _, r in rows),
        "ambiguous": sum(r["status"] == AMBIGUOUS for _, r in rows),
    }


def changed(before: list[tuple[str, dict]], after: list[tuple[str, dict]]) -> list[dict]:
    """The pairs whose status changed or whose rotation error moved by more than `MOVED_DEG`."""
    out = []
    for (label, a), (other, b) in zip(before, after, strict=True):
        if label != other:
            raise ValueError(f"the runs hold different pairs: {label!r} against {other!r}")
        moved = abs(a["rotation_error_deg"] - b["rotation_error_deg"]) > MOVED_DEG
        if a["status"] != b["status"] or moved:
            out.append(
                {
                    "pair": label,
                    "status": [STATUS_NAME[a["status"]], STATUS_NAME[b["status"]]],
                    "rotation_error_deg": [round(a["rotation_error_deg"], 4), round(b["rotation_error_deg"], 4)],
                }
            )
    return out


def markdown(base: str, new: str, levels: dict) -> str:
    lines = [
        f"`{base}` → `{new}`",
        "",
        "| σ, cm | found | successes | false successes | ambiguous |",
        "|---|---|---|---|---|",
    ]
    for level, v in levels.items():
        a, b = v["before"], v["after"]
        cells = " | ".join(f"{a[k]} → {b[k]}" for k in ("found", "success", "false_success", "ambiguous"))
        lines.append(f"| {level} | {cells} |")
    lines += ["", "| pair | status | rotation error, ° |", "|---|---|---|"]
    for v in levels.values():
        for c in v["changed"]:
            status = " → ".join(c["status"])
            error = " → ".join(f"{e:.3f}" for e in c["rotation_error_deg"])
            lines.append(f"| {c['pair']} | {status} | {error} |")
    return "\n".join(lines) + "\n"


def main(base: str, new: str, variant: str = "default") -> None:
    before, after = load(base, variant), load(new, variant)
    if before.keys() != after.keys():
        raise ValueError(f"the runs hold different noise levels: {sorted(before)} against {sorted(after)}")
    levels = {
        level: {
            "before": counts(before[level]),
            "after": counts(after[level]),
            "changed": changed(before[level], after[level]),
        }
        for level in before
    }
    write_json(f"draw_changes_{new}.json", {"base": base, "new": new, "variant": variant, "levels": levels})
    text = markdown(base, new, levels)
    (RESULTS / f"draw_changes_{new}.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main(*sys.argv[1:])
