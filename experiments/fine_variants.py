"""Fine-stage variants on a subset of the realistic benchmark, GICP on the same clouds.

`uv run --extra peers python experiments/fine_variants.py [--pairs 3] [--levels 0,0.5,1,2]
[--set anchors|cost|gates|edges|density|current|symmetric|stages|objective|starts] [--seed 0] [--from-truth]
[--peer-from-truth] [--by-target] [--only TEXT]`

`--set anchors` (the default): the planes' anchor (the default "hybrid", centroids everywhere,
points everywhere), the noise-free polish and the within-the-noise stop. `--set cost`: what the
stage's cost settings (`FineStage.points`, `steps`, `rounds`, `neighbours`) buy in accuracy
(docs, Findings: what the fine stage's cost buys). `--set gates`:
the inlier gate, the robust scale and the planar fraction (docs, Findings: the fine stage's
gates on two draws of pairs). `--set edges`: the planar fraction, whether the previous points
at edges and corners keep their planes (docs, Findings: planes at edges and corners). `--seed`
draws other pairs than the benchmark's (seed 0). `--set density`: the previous side thinned to
`FineStage.points` (the default) or kept whole (`FineStage.prev_points`; docs, Findings: a
dense previous side). `--set current`: the current points raw (the default) or smoothed onto
their neighbourhood's plane, on faces or everywhere (`FineStage.smooth_current`,
`_fine.SMOOTHED_FRACTION`; docs, Findings: a smoothed current side). `--set symmetric`:
one-way residuals (the default) or two-way (`FineStage.symmetric`), each against the thinned
previous side or every previous point (docs, Findings: two-way residuals). `--from-truth`
runs the fine stage alone from each pair's true motion (`fine_refine`), so that the errors
are those of the fine objective's own minimum; its "success" then counts the converged fits.
`--set stages`: the default (no refine) or with `Config.refine` (docs, Findings: the refine in the
default call). `--set objective`: the default against two-way residuals, 8192 points a side, both,
and two-way residuals with planes through the points (the nearest to GICP's cost); with
`--from-truth --peer-from-truth` GICP too starts from the true motion, so that both columns are
where each cost is least near the truth (docs, Findings: the fine objective's minimum against
GICP's). `--by-target` adds the median errors per target. `--only TEXT` runs only the variants
whose name contains TEXT. `--set starts`: the fine stage's starts as they are, or with the
principal alignment nearest the identity as a third (`FineStage.from_principal`; docs,
Findings: a start at the principal alignment).

`--pairs` pairs per target and noise level (`jaxpose.evaluation.realistic.make_cases`, seed 0),
one compiled program per variant (capacities sized once for all pairs, so times are those of
the largest bucket, not of the public call). Prints, per variant and noise level: found (< 1°
and < 5 cm), successes, false successes, median rotation and centroid errors and median time;
then the pairs not found. The table is printed, not committed (docs, Findings: the fine
stage's anchor on the realistic benchmark).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import statistics
import time

import equinox as eqx
import jax

import jaxpose as jp
from jaxpose import _fine
from jaxpose._estimate import _build_and_estimate
from jaxpose._fine import fine_refine
from jaxpose._poses import displacement_from_motion, motion_from_displacement
from jaxpose._problem import sized_batch_config
from jaxpose._programs import release_all
from jaxpose.evaluation import realistic


def gicp_rows(cases, from_truth: bool = False):
    """GICP on each case, from the identity, or from the true motion (`from_truth`)."""
    rows = []
    for case in cases:
        start = (case.rotation, case.translation) if from_truth else None
        t0 = time.perf_counter()
        R, t = realistic.gicp(case.prev.compact(), case.curr.compact(), start)
        rows.append({**realistic.errors(case, R, t), "ms": 1e3 * (time.perf_counter() - t0)})
    return rows


def benchmark_cases(args):
    """The noise levels of `args.levels` (comma-separated, cm), the benchmark's pairs at them
    (`args.pairs` per target and level, `args.seed`) and GICP's rows on those pairs, from the
    true motion where `args.peer_from_truth` is set (scripts without that flag: from the
    identity)."""
    levels = tuple(float(x) for x in args.levels.split(","))
    cases = realistic.make_cases(pairs=args.pairs, levels=levels, seed=args.seed)
    return levels, cases, gicp_rows(cases, getattr(args, "peer_from_truth", False))


def jaxpose_rows(cases, config, extra=None):
    """Every case through one compiled build-and-estimate; the compile time apart. `extra`: a
    function of each `Estimate` whose dict joins that case's row."""
    # The variants below change module constants read at trace time: drop every compiled
    # program, the public path's own (`Problem.build`'s, which `jax.clear_caches` misses) too.
    release_all()
    config = sized_batch_config([(c.prev, c.curr) for c in cases], config)
    run = eqx.filter_jit(_build_and_estimate)
    t0 = time.perf_counter()
    jax.block_until_ready(run(cases[0].prev, cases[0].curr, config, jax.random.key(0)))
    compile_s = time.perf_counter() - t0
    rows = []
    for i, case in enumerate(cases):
        t0 = time.perf_counter()
        est, _, _ = jax.block_until_ready(run(case.prev, case.curr, config, jax.random.fold_in(jax.random.key(0), i)))
        ms = 1e3 * (time.perf_counter() - t0)
        row = {**realistic.errors(case, est.rotation, est.translation), "ms": ms, "status": int(est.status)}
        rows.append(row | (extra(est) if extra else {}))
    return rows, compile_s


def truth_rows(cases, config):
    """The fine stage alone from each case's true motion (`fine_refine`); status 0 when it
    converged. The compile time apart, as in `jaxpose_rows`."""
    release_all()
    config = sized_batch_config([(c.prev, c.curr) for c in cases], config)
    fit = eqx.filter_jit(fine_refine)

    def problem_and_truth(case):
        problem = jp.Problem.build(case.prev, case.curr, config)
        truth = displacement_from_motion(problem.frame.origin, problem.frame.axes, case.rotation, case.translation)
        return problem, truth.astype(problem.d.dtype)

    problem, truth = problem_and_truth(cases[0])
    t0 = time.perf_counter()
    jax.block_until_ready(fit(problem, config, truth))
    compile_s = time.perf_counter() - t0
    rows = []
    for case in cases:
        problem, truth = problem_and_truth(case)
        t0 = time.perf_counter()
        result = jax.block_until_ready(fit(problem, config, truth))
        ms = 1e3 * (time.perf_counter() - t0)
        frame = problem.frame
        R, t = motion_from_displacement(frame.origin, frame.axes, result.params)
        rows.append({**realistic.errors(case, R, t), "ms": ms, "status": int(~result.converged)})
    return rows, compile_s


def report(name, cases, rows, gicp, compile_s, levels):
    def med(sel, key):
        return statistics.median(r[key] for r in sel)

    print(f"== {name} (compile {compile_s:.1f} s)")
    for sigma in levels:
        idx = [i for i, c in enumerate(cases) if c.sigma_cm == sigma]
        ours, peer = [rows[i] for i in idx], [gicp[i] for i in idx]
        false = sum(r["status"] == 0 and not r["found"] for r in ours)
        print(
            f"  σ {sigma} cm: jaxpose found {sum(r['found'] for r in ours)}/{len(ours)}, "
            f"success {sum(r['status'] == 0 for r in ours)}, false {false}, "
            f"rot {med(ours, 'rotation_error_deg'):.4f}°, centroid {med(ours, 'centroid_error_cm'):.4f} cm, "
            f"{med(ours, 'ms'):.0f} ms | GICP found {sum(r['found'] for r in peer)}, "
            f"rot {med(peer, 'rotation_error_deg'):.4f}°, centroid {med(peer, 'centroid_error_cm'):.4f} cm, "
            f"{med(peer, 'ms'):.0f} ms"
        )
    missed = [
        f"{c.label}: {r['rotation_error_deg']:.2f}°, {r['centroid_error_cm']:.2f} cm, status {r['status']}"
        for c, r in zip(cases, rows, strict=True)
        if not r["found"]
    ]
    print("  not found:", "; ".join(missed) or "none")


def report_by_target(cases, rows, gicp, levels):
    """Median rotation and centroid errors per target and noise level, jaxpose | GICP."""
    for sigma in levels:
        for target in dict.fromkeys(c.target for c in cases):
            idx = [i for i, c in enumerate(cases) if c.sigma_cm == sigma and c.target == target]
            ours, peer = [rows[i] for i in idx], [gicp[i] for i in idx]
            line = " | ".join(
                f"{statistics.median(r['rotation_error_deg'] for r in sel):.3f}°, "
                f"{statistics.median(r['centroid_error_cm'] for r in sel):.3f} cm"
                for sel in (ours, peer)
            )
            print(f"    σ {sigma} cm {target}: {line}")


@contextlib.contextmanager
def fine_constants(module=_fine, **values):
    """`module`'s constants (default `jaxpose._fine`) set to `values` inside the block (read
    when a program is traced), restored after it. A program compiled before the block is not
    traced again: set them before the first call of a process."""
    saved = {k: getattr(module, k) for k in values}
    for k, v in values.items():
        setattr(module, k, v)
    try:
        yield
    finally:
        for k, v in saved.items():
            setattr(module, k, v)


def fine_config(config, **settings):
    """`config` with its fine stage's `settings` changed."""
    return dataclasses.replace(config, fine=dataclasses.replace(config.fine, **settings))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--levels", default="0,0.5,1,2")
    parser.add_argument(
        "--set",
        default="anchors",
        choices=(
            "anchors",
            "cost",
            "gates",
            "edges",
            "density",
            "planes",
            "current",
            "symmetric",
            "stages",
            "objective",
            "starts",
        ),
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--from-truth", action="store_true")
    parser.add_argument("--only", default="", help="run only the variants whose name contains this")
    parser.add_argument("--peer-from-truth", action="store_true", help="GICP from the true motion too")
    parser.add_argument("--by-target", action="store_true", help="also print medians per target")
    args = parser.parse_args()
    levels, cases, gicp = benchmark_cases(args)
    default = jp.Config()
    point = fine_config(default, anchor="point")
    centroid = fine_config(default, anchor="centroid")
    variants = [
        ("default", default, {}),
        ("planes through the centroids", centroid, {}),
        ("planes through the points", point, {}),
        ("no noise-free polish", default, {"EXACT_RMS": 0.0}),
        ("no within-the-noise stop", default, {"NOISE_STEP": 0.0}),
    ]
    if args.set == "cost":
        settings = (("points", 2048), ("points", 8192), ("steps", 8), ("rounds", 10), ("neighbours", 12))
        variants = [("default", default, {})] + [
            (f"FineStage({name}={value})", fine_config(default, **{name: value}), {}) for name, value in settings
        ]
    if args.set == "gates":
        settings = (("inlier", 0.05), ("inlier", 0.08), ("planar_fraction", 0.85))
        variants = [
            ("default", default, {}),
            *((f"FineStage({name}={value})", fine_config(default, **{name: value}), {}) for name, value in settings),
            ("ROBUST_SCALE = 10", default, {"ROBUST_SCALE": 10.0}),
        ]
    if args.set == "edges":
        variants = [
            (
                f"FineStage(planar_fraction={value})",
                fine_config(default, planar_fraction=value),
                {},
            )
            for value in (1.0, 0.85, 0.7)
        ]
    if args.set == "density":
        variants = [
            ("default (previous side thinned to FineStage.points)", default, {}),
            (
                "FineStage(prev_points=2**20): every previous point",
                fine_config(default, prev_points=2**20),
                {},
            ),
        ]
    if args.set == "planes":
        variants = [
            (
                "FineStage(plane_source='selected'): planes among the thinned previous side",
                fine_config(default, plane_source="selected"),
                {},
            ),
            (
                "FineStage(plane_source='all'): planes among every previous point",
                fine_config(default, plane_source="all"),
                {},
            ),
            (
                "FineStage(plane_source='all_centroids'): normals among the thinned side, centroids among every point",
                fine_config(default, plane_source="all_centroids"),
                {},
            ),
            ("FineStage(prev_points=2**20): every previous point", fine_config(default, prev_points=2**20), {}),
        ]
    if args.set == "current":
        variants = [
            ("default (raw current points)", default, {}),
            (
                "FineStage(smooth_current=True): face-like current points smoothed",
                fine_config(default, smooth_current=True),
                {},
            ),
            (
                "FineStage(smooth_current=True), every current point with a plane smoothed",
                fine_config(default, smooth_current=True),
                {"SMOOTHED_FRACTION": 1.0},
            ),
        ]
    if args.set == "symmetric":
        variants = [
            ("default (one-way residuals)", default, {}),
            (
                "FineStage(symmetric=True): two-way residuals",
                fine_config(default, symmetric=True),
                {},
            ),
            (
                "FineStage(prev_points=2**20): every previous point, one-way",
                fine_config(default, prev_points=2**20),
                {},
            ),
            (
                "FineStage(symmetric=True, prev_points=2**20): two-way against every previous point",
                fine_config(default, symmetric=True, prev_points=2**20),
                {},
            ),
        ]
    if args.set == "stages":
        with_refine = dataclasses.replace(default, refine=jp.Refine())
        variants = [
            ("default (no refine: the fine stage from the search's best)", default, {}),
            ("Config(refine=Refine()): BFGS between the search and the fine stage", with_refine, {}),
        ]
    if args.set == "objective":
        variants = [
            ("default", default, {}),
            ("FineStage(symmetric=True)", fine_config(default, symmetric=True), {}),
            ("FineStage(points=8192)", fine_config(default, points=8192), {}),
            (
                "FineStage(symmetric=True, points=8192)",
                fine_config(default, symmetric=True, points=8192),
                {},
            ),
            (
                "FineStage(symmetric=True, anchor='point'): GICP-like",
                fine_config(default, symmetric=True, anchor="point"),
                {},
            ),
        ]
    if args.set == "starts":
        variants = [
            ("default (starts: the search's best and rest)", default, {}),
            (
                "FineStage(from_principal=True): also the principal alignment nearest the identity",
                fine_config(default, from_principal=True),
                {},
            ),
        ]
    variants = [v for v in variants if args.only in v[0]]
    rows_of = truth_rows if args.from_truth else jaxpose_rows
    for name, config, constants in variants:
        with fine_constants(**constants):
            rows, compile_s = rows_of(cases, config)
        report(name, cases, rows, gicp, compile_s, levels)
        if args.by_target:
            report_by_target(cases, rows, gicp, levels)


if __name__ == "__main__":
    main()
