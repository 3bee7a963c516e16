"""As-built correction, the goals' protocol of the issue: simulated builds of the trefoil (m = 4) and Bezier (a).

Each problem is designed with design_nlp. Each seed draws per-segment construction errors at sigma
1 deg / 0.02 / 2 % plus a systematic lambda offset; the robot built from a nominal realizes nominal +
deviations (the contract's rule: deviations persist from build to build, new values are built exactly).
A build is measured along the outer line at 200 points (or 15 markers), Gaussian noise 1.4 mm per
coordinate, in random order. Round 1 estimates from that measurement and corrects; the corrected nominal is
built with the SAME deviations and measured again; round 2 uses both measurements. Errors are those of the
built robot to the target: RMSE at the design's pairing and the tip's distance to the target's end.

Calibration: the prototypes of one construction method share the systematic lambda offset; the round-1
estimates of 5 seeds (5 prototypes) are combined by methods.correct.combine_systematic (as
``vine-nlp calibrate`` does) and compared with the true offset, for every group of 5 consecutive seeds.

Speed: one correction (estimate + correction, warm caches) timed in wall-clock and process CPU time, the
NLP functions compiled (VINE_NLP_CODEGEN=on unless set otherwise): a correction that built a solver (a new
structure, compiled on its first use on this machine) is run again and the second run timed. A few round-1
corrections are also timed with the NLP functions interpreted and compiled, in the same run.

Writes results/benchmarks/correct.md. Run: python benchmarks/bench_correct.py [--seeds 50] [--quick]
(--quick: 2 seeds, about 3 min on a quiet 2-core machine; the full protocol: 50 seeds, see the report's
closing line for how long it took)
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from common import ROOT, table, write_report

sys.path.insert(0, str(ROOT / "tests"))  # simulated builds: the tests' helpers
from simulate import draw_deviations, simulate_build  # noqa: E402

from vine_nlp.io.problem_file import load_problem
from vine_nlp.methods import compiled
from vine_nlp.methods import correct as C
from vine_nlp.methods.common import evaluate, pair_points
from vine_nlp.methods.nlp import design_nlp
from vine_nlp.methods.transcription import clear_caches, get_solver
from vine_nlp.model.chain import chain_frames
from vine_nlp.model.routing import Sigmas

SIGMAS = Sigmas.from_degrees(1.0, 0.02, 0.02)
LAMBDA_OFFSET = 0.02  # the systematic lambda offset of every simulated build
NOISE_MM = 1.4  # the paper's magnetic tracker, per coordinate
CASES = ("trefoil-m4", "bezier-a")
ADJUST = (("lambda",), ("lambda", "theta"))
PROTOTYPES = 5
def built_errors(pb, pairing, nominal, dev):
    """(RMSE to the target, tip error) of the robot with deviations ``dev`` built from ``nominal``."""
    r = C.apply_deviations(nominal, dev)
    rmse = evaluate(pb, r, pairing, "x").metrics["rmse"]
    tip = chain_frames(r.theta, r.lam, r.length, pb.diameter, r.initial_pose)[-1, :3, 3]
    return rmse, float(np.linalg.norm(tip - pb.target[-1]))


BUILDS = {"count": 0, "wall_s": 0.0}  # corrections that built a solver (timed again), and how long those first runs took


def timed(fn):
    """(result, wall s, CPU s) of ``fn()`` with warm caches: a call that built a solver (a structure seen for the
    first time in this process; compiled if it is new on this machine) is run again and the second run timed."""
    for _ in range(3):
        misses = get_solver.cache_info().misses
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        w, c = time.perf_counter() - w, time.process_time() - c
        if get_solver.cache_info().misses == misses:
            break
        BUILDS["count"] += 1
        BUILDS["wall_s"] += w
    return out, w, c


def per_iteration(est):
    """Milliseconds per estimate iteration, wall and CPU: the whole estimate (pairing, solves, Laplace step) over its
    IPOPT iterations."""
    n = max(est.iterations, 1)
    return 1000 * est.solve_time_s / n, 1000 * est.stats["cpu_time_s"] / n


def run_case(name, seeds, counts, mm):
    pb = load_problem(ROOT / "problems" / f"{name}.toml").problem
    design = design_nlp(pb)
    nom = design.routing
    pairing = pair_points(pb.target, pb.options.points_per_segment)
    D = pb.diameter
    noise = NOISE_MM / mm
    recs = []
    for seed in range(seeds):
        dev = draw_deviations(nom, SIGMAS, (0.0, LAMBDA_OFFSET, 1.0), seed=seed)
        e0 = built_errors(pb, pairing, nom, dev)
        for count in counts:
            m1 = C.Measurement(simulate_build(nom, dev, D, "outer", count, noise, seed=1000 + seed), "outer", 0)
            for adjust in ADJUST:
                r1, w1, c1 = timed(lambda: C.correct(pb, [nom], [m1], adjust=adjust, sigmas=SIGMAS, measurement_sigma=noise))
                n1 = r1.corrected.routing
                e1 = built_errors(pb, pairing, n1, dev)
                m2 = C.Measurement(simulate_build(n1, dev, D, "outer", count, noise, seed=2000 + seed), "outer", 1)
                r2, w2, c2 = timed(lambda: C.correct(pb, [nom, n1], [m1, m2], adjust=adjust, sigmas=SIGMAS, measurement_sigma=noise))
                e2 = built_errors(pb, pairing, r2.corrected.routing, dev)
                est = r1.estimate
                recs.append(dict(
                    seed=seed, count=count, adjust=",".join(adjust), e0=e0, e1=e1, e2=e2, wall=(w1, w2), cpu=(c1, c2),
                    rounds=(est.rounds, r2.estimate.rounds), iterations=(est.iterations, r2.estimate.iterations),
                    corr_iterations=(r1.corrected.iterations, r2.corrected.iterations),
                    lam_off=float(est.systematic[1]), lam_off_sd=float(est.systematic_std[1]), sys=est.systematic,
                    sys_sd=est.systematic_std, fit=r1.as_built.metrics["rmse"],
                    per_it=(per_iteration(est), per_iteration(r2.estimate)),
                ))
                print(name, seed, count, ",".join(adjust), f"{mm * e0[0]:.2f} -> {mm * e1[0]:.2f} -> {mm * e2[0]:.2f} mm, "
                      f"tip {mm * e0[1]:.1f} -> {mm * e1[1]:.1f}; {w1:.2f} s ({c1:.2f} cpu), {w2:.2f} s ({c2:.2f} cpu)", flush=True)
    return pb, design, recs


def speed_compare(name, seeds, mm):
    """Round-1 corrections (200 points, adjust lambda) with the NLP functions interpreted, then compiled: same
    measurements, same run. Every structure is built (and compiled) before the timed runs."""
    pb = load_problem(ROOT / "problems" / f"{name}.toml").problem
    nom = design_nlp(pb).routing
    D = pb.diameter
    ms = []
    for seed in range(seeds):
        dev = draw_deviations(nom, SIGMAS, (0.0, LAMBDA_OFFSET, 1.0), seed=seed)
        ms.append(C.Measurement(simulate_build(nom, dev, D, "outer", 200, NOISE_MM / mm, seed=1000 + seed), "outer", 0))
    mode = os.environ.get("VINE_NLP_CODEGEN")
    rows = []
    for label, setting in (("interpreted", "off"), ("compiled", "on")):
        os.environ["VINE_NLP_CODEGEN"] = setting
        clear_caches()  # the solvers are built again in this mode
        acc = []
        for m in ms:
            r, w, c = timed(lambda: C.correct(pb, [nom], [m], sigmas=SIGMAS, measurement_sigma=NOISE_MM / mm))
            e = r.estimate
            acc.append((e.rounds, e.iterations, r.corrected.iterations, *per_iteration(e), e.solve_time_s, e.stats["cpu_time_s"], w, c))
        a = np.array(acc, float)
        rows.append([name, label, seeds, f"{np.median(a[:, 0]):.0f}", f"{np.median(a[:, 1]):.0f}", f"{np.median(a[:, 2]):.0f}",
                     f"{np.median(a[:, 3]):.1f} / {np.median(a[:, 4]):.1f}", f"{np.median(a[:, 5]):.2f} / {np.median(a[:, 6]):.2f}",
                     f"{np.median(a[:, 7]):.2f} / {np.median(a[:, 8]):.2f}", f"{a[:, 7].max():.2f} / {a[:, 8].max():.2f}"])
        print(rows[-1], flush=True)
    if mode is None:
        os.environ.pop("VINE_NLP_CODEGEN")
    else:
        os.environ["VINE_NLP_CODEGEN"] = mode
    clear_caches()
    return rows


def med(v):
    return float(np.median(v))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=50, help="seeds per problem (the protocol: 50)")
    ap.add_argument("--speed-seeds", type=int, default=3, help="seeds of the before/after speed comparison")
    ap.add_argument("--quick", action="store_true", help="2 seeds, no speed comparison (a smoke run)")
    args = ap.parse_args()
    if args.quick:
        args.seeds, args.speed_seeds = 2, 0
    # the goal's timing is of the compiled NLP functions (the default where a compiler is found); =off times them interpreted
    os.environ.setdefault("VINE_NLP_CODEGEN", "on")
    mm = 10.0  # cm -> mm (both problems are in cm)
    load0 = os.getloadavg()[0]
    t_start = time.perf_counter()
    speed = []
    for name in CASES if args.speed_seeds else ():
        speed += speed_compare(name, args.speed_seeds, mm)
    BUILDS.update(count=0, wall_s=0.0)  # the time table's count
    interpreted0 = compiled.stats["interpreted"]  # VINE_NLP_CODEGEN=auto may fall back (one note)
    goal_rows, cal_rows, time_rows, designs = [], [], [], []
    all_recs = {}
    functions = "compiled" if compiled.mode() != "off" and compiled.compiler() else "interpreted"
    for name in CASES:
        pb, design, recs = run_case(name, args.seeds, (200, 15), mm)
        all_recs[name] = recs
        designs.append(f"{name}: {design.routing.segments} segments, designed RMSE {mm * design.metrics['rmse']:.3f} mm")
        for count in (200, 15):
            for adjust in ADJUST:
                rs = [r for r in recs if r["count"] == count and r["adjust"] == ",".join(adjust)]
                r0, t0 = med([r["e0"][0] for r in rs]), med([r["e0"][1] for r in rs])
                r1, t1 = med([r["e1"][0] for r in rs]), med([r["e1"][1] for r in rs])
                r2, t2 = med([r["e2"][0] for r in rs]), med([r["e2"][1] for r in rs])
                ok1 = "yes" if r0 / r1 >= 3 and t0 / t1 >= 3 else "NO"
                ok2 = "yes" if r0 / r2 >= 6 else "NO"
                goal_rows.append([name, f"{count} {'points' if count > 15 else 'markers'}", ",".join(adjust), len(rs),
                                  f"{mm * r0:.2f} / {mm * t0:.1f}", f"{mm * r1:.2f} / {mm * t1:.1f}", f"{mm * r2:.2f} / {mm * t2:.1f}",
                                  f"{r0 / r1:.1f}x / {t0 / t1:.1f}x ({ok1})", f"{r0 / r2:.1f}x / {t0 / t2:.1f}x ({ok2})"])
            rs = [r for r in recs if r["count"] == count]
            walls = [w for r in rs for w in r["wall"]]
            cpus = [c for r in rs for c in r["cpu"]]
            its = [p for r in rs for p in r["per_it"]]
            time_rows.append([name, count, functions, len(walls), f"{med(walls):.2f}", f"{max(walls):.2f}", f"{med(cpus):.2f}",
                              f"{max(cpus):.2f}", f"{med([p[0] for p in its]):.1f} / {med([p[1] for p in its]):.1f}",
                              f"{med([r['rounds'][0] for r in rs]):.0f} / {med([r['rounds'][1] for r in rs]):.0f}",
                              f"{med([r['iterations'][0] for r in rs]):.0f} / {med([r['iterations'][1] for r in rs]):.0f}",
                              f"{med([r['corr_iterations'][0] for r in rs]):.0f}"])
            # calibration: groups of PROTOTYPES consecutive seeds, their round-1 estimates (adjust lambda)
            one = [r for r in rs if r["adjust"] == "lambda"]
            errs, ses = [], []
            for g in range(len(one) // PROTOTYPES):
                grp = one[g * PROTOTYPES : (g + 1) * PROTOTYPES]
                mean, se, _ = C.combine_systematic([r["sys"] for r in grp], [r["sys_sd"] for r in grp])
                errs.append(abs(mean[1] - LAMBDA_OFFSET))
                ses.append(se[1])
            if errs:
                within = sum(e <= 0.005 for e in errs)
                cal_rows.append([name, count, len(errs), f"{med(errs):.4f}", f"{max(errs):.4f}", f"{med(ses):.4f}",
                                 f"{within} of {len(errs)}", f"{med([abs(r['lam_off'] - LAMBDA_OFFSET) for r in one]):.4f}"])
    load1 = os.getloadavg()[0]
    if functions == "compiled" and compiled.stats["interpreted"] > interpreted0:
        functions = f"compiled, {compiled.stats['interpreted'] - interpreted0} structures interpreted (no working compiler)"
    desc = (
        f"Problems: {'; '.join(designs)} (design_nlp). Seeds per problem: {args.seeds} (the issue's protocol asks for 50"
        f"{'' if args.seeds >= 50 else '; fewer ran here, see the count column'}). Construction errors per segment at sigma "
        f"1 deg / 0.02 / 2 % plus a systematic lambda offset of {LAMBDA_OFFSET}; deviations persist from build to build and the new "
        f"values are built exactly. Each build measured on the outer line at 200 points (or 15 markers), noise {NOISE_MM} mm per "
        "coordinate, random order. Round 1: the first measurement; round 2: the corrected nominal built and measured again, "
        "both measurements used. Errors of the built robot to the target in mm (RMSE at the design's pairing / tip distance), "
        f"medians over the seeds. Load average {load0:.1f} at the start, {load1:.1f} at the end (2 cores, shared); "
        f"the whole run took {(time.perf_counter() - t_start) / 60:.0f} min."
    )
    t_goal = table(["problem", "measured", "adjust", "seeds", "before: RMSE / tip", "after round 1", "after round 2",
                    "gain round 1: RMSE / tip (goal >= 3x both)", "gain round 2 (goal RMSE >= 6x)"], goal_rows)
    t_cal = table(["problem", "measured", "groups of 5 prototypes", "median abs. error", "max abs. error", "median std. error",
                   "within 0.005", "one prototype: median abs. error"], cal_rows)
    t_time = table(["problem", "measured", "NLP functions", "corrections", "median wall [s]", "max wall [s]", "median CPU [s]",
                    "max CPU [s]", "ms per estimate iteration (wall / CPU)", "ICP rounds (round 1 / 2)", "estimate iterations (1 / 2)",
                    "correction iterations"], time_rows)
    blocks = ["Medians of the built errors (goals: round 1 at least 3x lower RMSE and tip error; round 2 at least 6x lower RMSE):",
              t_goal,
              f"Calibration: the systematic lambda offset ({LAMBDA_OFFSET}) recovered from {PROTOTYPES} prototypes "
              "(round-1 estimates combined as `vine-nlp calibrate` does; goal within 0.005):", t_cal,
              "Time per correction (estimate + correction, warm caches; goal <= 2 s). Wall-clock on the shared machine "
              f"and the process's CPU time, per correction (round 1 and round 2 each count); NLP functions {functions} "
              f"(VINE_NLP_CODEGEN={compiled.mode()}). {BUILDS['count']} corrections built a solver on their first run "
              f"({BUILDS['wall_s']:.1f} s wall in all, compiling included) and were timed on a second run. "
              "ms per estimate iteration: the whole estimate (pairing, solves, Laplace step) over its IPOPT iterations:", t_time]
    if speed:
        blocks += ["Speed: the NLP functions interpreted against compiled, same run, round 1 with 200 points, adjust lambda "
                   "(medians; every structure built before the timed runs). The estimate's pairing is data (slot fractions, "
                   "points, weights 0 on unused slots, one block instance per slot), so one structure per (segments, slots, "
                   "builds) serves every ICP round and is compiled once.",
                   table(["problem", "NLP functions", "seeds", "ICP rounds", "estimate iterations", "correction iterations",
                          "ms per estimate iteration (wall / CPU)", "estimate [s] (wall / CPU)", "correction median [s] (wall / CPU)",
                          "correction max [s] (wall / CPU)"], speed)]
    write_report("correct", "As-built correction: the goals' protocol (trefoil m = 4, Bezier (a))", desc, *blocks)


if __name__ == "__main__":
    main()
