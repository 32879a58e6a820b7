"""How many ROS2 steps per sample ext-sampled-soft's continuous reference needs.

For each case of ``ext-sampled-soft`` (its ``SampledConfig``), the continuous loop
(``continuous_soft_loop``: Theorem 10 acting at every ROS2 step) runs on the nominal plant
and on every plant of the grid at each count of ``--substeps``, and prints the CPU-s
(process clock) and the rms of ‖q_d − q‖ over the metric window (NaN: the run diverged),
nominal plant first, then the grid in its order. A count is enough for a case when its
rms agree with the next larger count's to the accuracy the comparison needs (the
experiment compares sampled with continuous rms within a factor 2).

Usage::

    .venv/bin/python benchmarks/continuous_substeps.py --cases planar,3d,user_3seg \\
        --substeps 10,5,3

2026-12-06 (load ~2 on 2 CPUs): 3d 10/5/3 steps 10.5/5.5/3.4 CPU-s, rms within 0.05 %
(5 against 10) and 0.25 % (3 against 10) on all nine plants; planar 5 against 10 up to
1.4 %; user_3seg at 5 diverged on one corner. Measurements, never assertions.
"""
from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import softgen.experiments.ext_sampled_soft as E
from softgen.control.soft import reference_block
from softgen.control.soft_sampled import ModelScale


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="planar,3d,user_3seg")
    ap.add_argument("--substeps", default="10,5,3")
    args = ap.parse_args()
    c = E.SampledConfig()
    tags = args.cases.split(",")
    if unknown := sorted(set(tags) - {k.tag for k in c.cases}):
        ap.error(f"--cases: expected tags among {', '.join(k.tag for k in c.cases)}, got "
                 f"{', '.join(unknown)}")
    try:
        counts = [int(s) for s in args.substeps.split(",")]
    except ValueError:
        counts = []
    if not counts or min(counts) < 1:
        ap.error(f"--substeps: expected positive integers separated by commas, got "
                 f"{args.substeps!r}")
    for case in E._selected(c):
        if case.tag not in tags:
            continue
        dyn, lin = E._dynamics(case.model)
        ref = reference_block("ref", c.dt, case.amplitude, case.omega, case.phase,
                              unit=case.unit)
        for n in counts:
            k = dataclasses.replace(case, substeps=n)
            loop = E.continuous_soft_loop(f"substeps_{case.tag}_{n}", dyn, ref, c.dt, lin, n)
            t0, out = time.process_time(), []
            for g in [None, *c.grid]:
                ps = ModelScale() if g is None else ModelScale(*g)
                dur = case.duration if g is None else min(case.duration, c.grid_duration)
                tr = E._run_loop(loop, "continuous", k, c, f"{case.tag} {n} {g}", ps, dur)
                e = np.linalg.norm(tr["ref.q_d"] - tr[f"{loop.plant}.q"], axis=1)
                last = tr.t >= dur - c.metric_window
                out.append(float(np.sqrt(np.mean(e[last] ** 2)))
                           if tr.stopped_at is None else float("nan"))
            print(f"{case.tag} {n} steps {time.process_time() - t0:.2f} CPU-s rms "
                  + " ".join(f"{v:.6e}" for v in out), flush=True)


if __name__ == "__main__":
    main()
