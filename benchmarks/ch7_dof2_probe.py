"""Which springs the 2-DoF non-invasive estimate of ``ch7-noninvasive-protocol`` lands on.

Measurements, not assertions. The 2-DoF run (``planar_2link``, two qbmove VSAs, plant
springs ``spring_scale`` = 1.2 × the datasheet's) is made once as the experiment makes it
(its config, ``--phase-duration`` per phase), then the headline estimator (Theorem 4 with
the 0.5 Hz low-pass, P₁, P₂ of section 7.4) is replayed offline on the same plant signals
with one thing changed at a time. Each row prints the mean of σ̂/σ_plant per joint over
time windows: 1 is the plant's springs, 1/1.2 = 0.833 the datasheet's.

Rows: as run (8192-count encoders); every encoder exact; exact link encoder with quantised
motor encoders and the reverse; the RLS started at 5 s and 10 s instead of when the
observer converges; P(0) = 10⁸ I instead of P₁, P₂; and new plant runs with springs 1.0 and
1.4 × the datasheet's (the estimator has no spring model, so it should follow the plant).

    .venv/bin/python benchmarks/ch7_dof2_probe.py                      # the --quick phases
    .venv/bin/python benchmarks/ch7_dof2_probe.py --phase-duration 400 # the full run
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from softgen.estimation.estimators import StiffnessEstimator
from softgen.estimation.offline import estimation_result, offline_diagram, recorded
from softgen.experiments.ch7_noninvasive_protocol import NoninvasiveProtocolConfig
from softgen.modelfile.load import load_model
from softgen.studies.estimation import estimator, protocol_run
from softgen.studies.scenario import Scenario


def ratios(t, sigma_hat, sigma, edges) -> str:
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        w = (t >= a) & (t < b) & np.isfinite(sigma_hat[:, 0])
        out.append(f"[{a:g},{b:g}) " + "/".join(
            f"{np.mean(sigma_hat[w, i] / sigma[w, i]):6.3f}" for i in range(sigma.shape[1])))
    return "  ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--phase-duration", type=float, default=40.0,
                    help="s per phase (40 = the experiment's --quick, 400 = its full run)")
    ap.add_argument("--starts", default="5,10",
                    help="comma-separated times [s] at which a replay starts its RLS")
    a = ap.parse_args()
    d = a.phase_duration
    c = replace(NoninvasiveProtocolConfig(), phase_duration=d)
    edges = [0.0, d / 8, d / 4, d / 2, d, 1.5 * d, 2 * d]
    model = load_model("planar_2link")
    t = c.samples()
    est = estimator(model, "noninvasive", c, lowpass=c.lowpass)

    def run(scale):
        cs = replace(c, spring_scale=scale)
        return protocol_run(cs, model, "ch7_dof2_probe", cs.sigma_d_dof2,
                            {"est": est.block("est", p0=c.p0_dof2)})

    def replay(e, r, exact=(), p0=c.p0_dof2):
        ext = {s: r.tr[f"plant.{s}" if s in exact else f"enc.{s}_m"] for s in ("q", "qa", "qb")}
        tr = Scenario("ch7_dof2_replay", offline_diagram(e, p0=p0), steps=t.size,
                      externals=ext, record=recorded()).run()
        return estimation_result(e, tr).sigma_hat

    r = run(c.spring_scale)
    rows = {"as run (8192 counts)": estimation_result(est, r.tr, "est").sigma_hat,
            "all encoders exact": replay(est, r, ("q", "qa", "qb")),
            "exact link, quantised motors": replay(est, r, ("q",)),
            "quantised link, exact motors": replay(est, r, ("qa", "qb")),
            "P(0) = 1e8 I": replay(est, r, p0=[1e8, 1e8])}
    for start in (float(v) for v in a.starts.split(",")):
        late = StiffnessEstimator(model, replace(est.config, warmup=int(round(start / c.dt))))
        rows[f"RLS from t = {start:g} s"] = replay(late, r)
    print(f"est/plant stiffness per joint, phases of {d:g} s; datasheet = "
          f"{1 / c.spring_scale:.3f}")
    for k, v in rows.items():
        print(f"{k:30s} {ratios(t, v, r.truth.sigma, edges)}", flush=True)
    for scale in (1.0, 1.4):
        rs = run(scale)
        print(f"{f'plant springs {scale:g} x datasheet':30s} "
              f"{ratios(t, estimation_result(est, rs.tr, 'est').sigma_hat, rs.truth.sigma, edges)}",
              flush=True)


if __name__ == "__main__":
    main()
