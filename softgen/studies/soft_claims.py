"""Claims of the chapter-12 experiments read from their metric records (thesis §12.2):
thresholds, and the checks shared by ``ch12-planar-pcc``, ``ch12-affine-pendulum``,
``ch12-3d-pcc`` (:mod:`softgen.experiments.ch12_soft`). Records are read by (quantity,
suffix), never by parsing names; an absent record makes the claim "not checked"."""
from __future__ import annotations

from softgen.core.metrics import Metrics, finding, graded, not_checked, num
from softgen.studies.indices import DRIFT

#: Thresholds of the findings (unit of the configuration: rad, or m for the 3D robot).
CONVERGED = {"planar": 0.02, "pendulum": 0.05, "3d": 0.02}     # rms ‖e‖, last 10 s
ROBUST = {"planar": 0.1, "pendulum": 0.1, "3d": 0.05}          # with noise σ = 0.032
BOUNDED = 100.0                                                # max ‖π̂‖


def records_of(m: Metrics, quantity: str, suffixes) -> dict[str, float] | list[str]:
    """``{suffix: value}`` of ``quantity`` per variant, or the records it lacks."""
    got = {s: m.find(quantity, suffix=s) for s in suffixes}
    lost = [f"{quantity} ({s or 'headline'})" for s, r in got.items() if r is None]
    return lost or {s: r.value for s, r in got.items()}


def converges_claim(m, claim, suffixes, tol, unit) -> dict:
    v = records_of(m, "position_rms_error", suffixes)
    if isinstance(v, list):
        return not_checked(claim, v)
    return finding(claim, graded([x < tol for x in v.values()]),
                   "; ".join(f"{s or 'headline'}: {num(x)} {unit}" for s, x in v.items())
                   + f" (rms of ‖q_d − q‖ over the last 10 s); threshold < {tol:g} {unit}.")


def bounded_claim(m, claim, suffixes) -> dict:
    """Bounded as a trend: max ‖π̂‖ below :data:`BOUNDED` *and* no drift — the linear
    trend of ‖π̂‖ over the second half changes it by less than :data:`DRIFT` (issue 24)."""
    v = records_of(m, "parameter_estimate_max_norm", suffixes)
    d = records_of(m, "parameter_estimate_norm_drift", suffixes)
    if isinstance(v, list) or isinstance(d, list):
        return not_checked(claim, (v if isinstance(v, list) else []) +
                           (d if isinstance(d, list) else []))
    steady = {s: d[s] is not None and d[s] < DRIFT for s in suffixes}
    drifting = [s for s in suffixes if not steady[s]]
    return finding(claim, graded([max(v.values()) < BOUNDED, *steady.values()]),
                   f"largest max_t ‖π̂(t)‖ over the scenarios {num(max(v.values()))} (from "
                   f"π̂(0) = 0; threshold < {BOUNDED:g}); change of ‖π̂‖ along its trend over "
                   "the second half: " + ", ".join(f"{num(d[s])} ({s or 'headline'})"
                                                   for s in suffixes)
                   + f" (threshold < {DRIFT:g}" + (f"; still drifting: "
                                                   f"{', '.join(x or 'headline' for x in drifting)}"
                                                   if drifting else "") + ").")


def force_estimate_text(m: Metrics, suffix: str) -> str:
    """' (f̂ at the end: x, y[, z] N)' of a run with force columns, from its records."""
    keys = [k for k in m.keys() if k.startswith("force_estimate_")
            and k.endswith(f"_final_{suffix}")]
    return f" (f̂ at the end {', '.join(num(m[k]) for k in keys)} N)" if keys else ""


def columns_claim(m, claim, pairs, graded_on, tol, unit) -> dict:
    """Force columns (beyond the thesis): rms error of each (without, with) pair of
    variants; the verdict grades ``graded_on`` (variants with columns) against ``tol``."""
    v = records_of(m, "position_rms_error", [x for p in pairs for x in p])
    if isinstance(v, list):
        return not_checked(claim, v)
    return finding(claim, graded([v[s] < tol for s in graded_on]), "; ".join(
        f"{a}: {num(v[a])} {unit} without, {num(v[b])} {unit} with force columns"
        f"{force_estimate_text(m, b)}" for a, b in pairs)
        + f" (rms of ‖q_d − q‖ over the last 10 s); threshold < {tol:g} {unit}.")
