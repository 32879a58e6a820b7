"""``ch6-electric-invasive``: section 6.2.3, Fig. 6.5-6.6, Table 6.1.

The two-link arm of Table 7.1 with a qbmove VSA per joint (``planar_2link``:
b = 3e-6 kg m², d = 1e-6 N m s, a/k per joint as NOTES section 2 item 7) under
open-loop sinusoidal motor torques of 0.15 N m at 0.25, 0.06, 0.17 and 0.08 Hz
(τ_11, τ_12, τ_21, τ_22), T = 10⁻³ s. One Theorem 2 observer (L = 2) per motor and
one RLS per motor on (φ, φ³, φ⁵, φ⁷), Π̂(0) = 0, P(0) = 10⁸ I₄; plant and estimator
run in one diagram (:mod:`softgen.plants.qbmove`).

Link damping (issue 13): the model has none, and the open-loop torques on joint 2 sum
to about 0.30 N m while gravity holds at most m₂c₂g ≈ 0.115 N m, so undamped links
spin freely (``undamped_*``: ``undamped_max_link_speed_joint*``). The headline run
gives each link β = 0.5 N m s/rad (``link_damping``): chosen so that the net
open-loop torque (≤ 0.3 N m) balances the damping at ≈ 0.3/β = 0.6 rad/s, so the
links swing instead of spinning, as in Fig. 6.5 (``max_link_speed_joint*`` reports
the speeds reached); the thesis's motor parameters are kept. A link faster than
``runaway_speed`` is reported as a runaway (finding).

The thesis does not say how long it ran nor over which interval Table 6.1 is
computed; we run 60 s and compute the indices after the first 10 %. MSREP in
percent, ours and the thesis's alike (issue 32: one unit per quantity). Table 6.1 labels
its MSREP column [%], but its numbers are fractions, as Tables 6.2-6.3's are: MSE/MSREP is
the mean square of the truth, so the printed stiffness pair (1.84e-7, 3.34e-7) implies an
rms stiffness of 0.74 N m/rad read as a fraction and 7.4 N m/rad read as percent, and the
springs reach at most a k cosh(a φ) ≈ 1.04 N m/rad each at the 0.38-rad deflections that
0.15 N m of motor torque produces (k sinh(a φ) = 0.15); the torque pair (1.49e-11,
2.85e-9) likewise gives 0.072 N m against 0.72 N m, above the motor torque. So ``thesis``
holds Table 6.1's MSREP × 100. Torque entries: the joint's total
flexibility torque from the RLS models; stiffness: σ̂_a + σ̂_b.

Grading (issue 32): Table 6.1 in the printed setting (``undamped_*``, kind "thesis") and
on the damped variant (kind "variant"), each index in the band [1/3, 3] of the printed
number: a simulation whose every number is printed but the link damping (which we choose)
and the run's length and window (which we choose too); 3× in a mean square is 1.7× in the
rms error, what those choices move (the T/2 and T/4 reruns of ch6-pneumatic-invasive move
its MSE 3.5× per halving of T).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from softgen.studies.indices import mse, msrep
from softgen.experiments.registry import (Config, Experiment, Metrics, banded, finding,
                                          graded, not_checked, num)
from softgen.modelfile.load import load_model
from softgen.runtime.simulate import save_traces
from softgen.studies.estimation import (QbmoveStudyConfig, estimator, figures,
                                        polynomial_fit_stiffness, qbmove_run, run_figure,
                                        variant_records)
from softgen.symbolic.actuators import QbmoveSprings


@dataclass(frozen=True)
class ElectricInvasiveConfig(QbmoveStudyConfig):
    model: str = "planar_2link"
    duration: float = 60.0
    substeps: int = 10              # RK4 at 0.1 ms: the motor-spring modes reach ~600 rad/s
    torque_amplitude: float = 0.15  # N m
    torque_frequency: tuple[float, ...] = (0.25, 0.06, 0.17, 0.08)  # Hz: τ_11, τ_12, τ_21, τ_22
    link_damping: float = 0.5       # N m s/rad on each link (see the module docstring)
    undamped_variant: bool = True
    runaway_speed: float = 20.0     # rad/s: a link faster than this has run away
    # The undamped run repeated with the torque amplitude changed by this relative amount:
    # if its indices move by O(1), the runaway is chaotic and its numbers are only
    # orders of magnitude (they move with any round-off change of the dynamics too).
    perturbation: float = 1e-12


#: Table 6.1; its MSREP column is a fraction (module docstring), held here in percent.
THESIS = {"stiffness_mse_joint1": 1.84e-7, "stiffness_mse_joint2": 1.92e-7,
          "stiffness_msrep_joint1": 100 * 3.34e-7, "stiffness_msrep_joint2": 100 * 3.38e-7,
          "torque_mse_joint1": 1.49e-11, "torque_mse_joint2": 1.62e-11,
          "torque_msrep_joint1": 100 * 2.85e-9, "torque_msrep_joint2": 100 * 2.84e-9}
#: k of the band [1/k, k] Table 6.1's indices are graded in (module docstring).
BAND = 3.0
#: Table 6.1 beside every run of the same indices: the undamped runs are section 6.2.3
#: taken literally, and the observer's torque is the other reading of "torque estimate".
THESIS_ROWS = {
    **THESIS, **{f"undamped_{k}": v for k, v in THESIS.items()},
    **{f"undamped_perturbed_{k}": v for k, v in THESIS.items() if k.startswith("stiffness_mse")},
    **{f"{p}observer_{k}": v for p in ("", "undamped_") for k, v in THESIS.items()
       if k.startswith("torque_mse")}}
_OURS = {
    "estimator_seconds_per_step": "our timing",
    "max_abs_deflection": "what the run reached (runaway check); the thesis prints none",
    "max_link_speed_joint*": "what the run reached (runaway check); the thesis prints none",
    "max_abs_link_angle_joint*": "what the run reached (runaway check); the thesis prints none",
    "polynomial_fit_stiffness_msrep_joint*": "bound of the odd-polynomial model class, ours",
    "motor_mode_max_rad_s": "fastest motor-spring mode of the run, ours",
    "nyquist_rad_s": "π/T of the run, ours",
    "metric_window_*": "the window the indices cover (the thesis does not state it)",
}
NOT_IN_THESIS = {
    **_OURS, **{f"undamped_{k}": v for k, v in _OURS.items()},
    "undamped_perturbed_max_link_speed_joint*": "chaos check of the undamped runaway, ours",
    "link_damping": "our link damping (issue 13); the thesis's model has none",
    "runaway_speed_bound": "our runaway threshold",
    "undamped_perturbation": "our chaos check's relative torque change",
}
_FIG = {"": "with link damping 0.5 N m s/rad (ours, issue 13)",
        "undamped_": "without link damping, section 6.2.3 as printed",
        "perturbed_": "undamped, torque amplitude changed by 1e-12 (chaos check)"}
CAPTIONS = {
    **{f"{p}estimation.png": f"True and estimated stiffness and flexibility torque of both "
                             f"joints, {w}, and their errors; mirrors Fig. 6.6."
       for p, w in _FIG.items()},
    **{f"{p}inputs_deflections_links.png": f"Motor torques, spring deflections and link angles "
                                           f"of the open-loop run {w}; mirrors Fig. 6.5."
       for p, w in _FIG.items()},
}


def run(c: ElectricInvasiveConfig, out) -> Metrics:
    m = _run(c, out, c.link_damping, "")
    m.add("link_damping", c.link_damping, "N m s/rad")
    m.add("runaway_speed_bound", c.runaway_speed, "rad/s")
    if c.undamped_variant:
        m.extend(_run(c, out, None, "undamped_"), prefix="undamped_")
        cp = c.replace(torque_amplitude=c.torque_amplitude * (1 + c.perturbation))
        m.extend(_run(cp, out, None, "perturbed_"), prefix="undamped_perturbed_",
                 keep=lambda r: r.quantity in ("stiffness_mse", "max_link_speed"))
        m.add("undamped_perturbation", c.perturbation, "1")
    return m


def _run(c: ElectricInvasiveConfig, out, beta, pre: str) -> Metrics:
    model = load_model(c.model)
    n = model.dof
    est = estimator(model, "electric", c)
    K = int(round(c.duration / c.dt)) + 1
    t = np.arange(K) * c.dt
    # Plant input order: τ_a of each joint, then τ_b; the thesis's τ_ij is joint i, motor j.
    f = np.array(c.torque_frequency).reshape(n, 2)
    U = c.torque_amplitude * np.sin(2 * np.pi * np.outer(t, np.concatenate([f[:, 0], f[:, 1]])))
    tr, truth = qbmove_run(f"ch6_electric_invasive_{'un' if beta is None else ''}damped",
                           model, c, {"est": est.block("est")}, K=K, inputs={"tau_motor": U},
                           x0={}, servo=False, link_damping=beta)
    m, res, mask = variant_records(tr, truth, est, "est", c.metric_window, truth.tau_e)
    for i in range(n):
        m.add("observer_torque_mse", mse(truth.tau_e[mask, i], res.tau_uio[mask, i]),
              "(N m)^2", joint=i + 1)
    phi = np.hstack([tr["plant.q"] - tr["plant.qa"], tr["plant.q"] - tr["plant.qb"]])
    m.add("max_abs_deflection", np.abs(phi).max(), "rad")
    for i in range(n):
        m.add("max_link_speed", np.abs(tr["plant.qd"][:, i]).max(), "rad/s", joint=i + 1)
        m.add("max_abs_link_angle", np.abs(tr["plant.q"][:, i]).max(), "rad", joint=i + 1)
    # Two measured limits on the accuracy: the least-squares fit of the odd polynomial
    # to the *true* spring torques (the RLS model class), and the fastest
    # motor-against-spring mode sqrt(σ_j/b_j) met, beside the Nyquist rate π/T.
    fit = polynomial_fit_stiffness(phi[mask], truth.spring_torque[mask], c.powers)
    for i in range(n):
        m.add("polynomial_fit_stiffness_msrep", msrep(truth.sigma[mask, i], fit[:, i]), "%",
              joint=i + 1)
    sp = QbmoveSprings(model)
    m.add("motor_mode_max_rad_s", np.sqrt(truth.spring_stiffness / np.concatenate(
        [sp.b_a, sp.b_b])).max(), "rad/s")
    m.add("nyquist_rad_s", np.pi / c.dt, "rad/s")
    m.add("metric_window_start", t[mask][0], "s")
    m.add("metric_window_end", t[mask][-1], "s")
    run_figure(out / f"{pre}inputs_deflections_links.png", t, U, phi, tr["plant.q"],
               title=f"open-loop run, link damping {beta or 0:g} N m s/rad (cf. Fig. 6.5)")
    save_traces(out / f"{pre}traces.npz", t=t, tau_motor=U, tau_e=truth.tau_e,
                        sigma=truth.sigma, sigma_hat=res.sigma_hat, tau_hat=res.tau_hat,
                        tau_uio=res.tau_uio, **{f"x_{s}": tr[f"plant.{s}"] for s in
                                                ("q", "qd", "qa", "qad", "qb", "qbd")},
                        **{f"theta_{r}": v for r, v in res.theta.items()})
    figures(out, pre, tr, truth.sigma, truth.tau_e, res, est, "electric, invasive")
    return m


def _table61(m: Metrics, pre: str, quantity: str, where: str, kind: str) -> dict:
    """Table 6.1's ``quantity`` indices (MSE and MSREP, both joints) of the run ``pre``,
    each in the band [1/:data:`BAND`, :data:`BAND`] of the printed number."""
    what = {"stiffness": "stiffness", "torque": "flexibility-torque"}[quantity]
    printed = " / ".join(num(THESIS[f"{quantity}_mse_joint{j}"]) for j in (1, 2))
    claim = f"Table 6.1: {what} MSE {printed} (joints 1/2) and MSREP under open-loop torques, {where}"
    keys = [f"{pre}{quantity}_{i}_joint{j}" for i in ("mse", "msrep") for j in (1, 2)]
    flat = dict(m.items())
    if lost := [k for k in keys if k not in flat]:
        return not_checked(claim, lost, kind=kind, band=BAND)
    ok, ev = banded(flat, THESIS_ROWS, keys, BAND)
    return finding(claim, graded(ok), ev + " (MSREP in %, Table 6.1's fractions × 100)",
                   kind=kind, metrics=keys, band=BAND)


def findings(m: Metrics, c: Config | None = None) -> list[dict]:
    """Table 6.1 in the band [1/3, 3] (printed setting and damped variant); runaway links
    reported (both runs)."""
    out = []
    if m.find("stiffness_mse", joint=1, prefix="undamped_") is not None:
        out += [_table61(m, "undamped_", q, "in the printed setting (no link damping)",
                         "thesis") for q in ("stiffness", "torque")]
    beta = num(m.value("link_damping"))
    out += [_table61(m, "", q, f"on the damped variant (link damping {beta} N m s/rad added, "
                               "issue 13)", "variant") for q in ("stiffness", "torque")]
    bound = m.value("runaway_speed_bound")
    for pre in ("", "undamped_"):
        v = m.per_joint("max_link_speed", prefix=pre)
        if not v:
            continue
        angle = m.per_joint("max_abs_link_angle", prefix=pre)
        s = m.per_joint("stiffness_mse", prefix=pre)
        out.append(finding(
            f"{'Damped' if not pre else 'Undamped'} run: the links stay below "
            f"{num(bound)} rad/s (no runaway)",
            "reproduced" if max(v.values()) < bound else "not reproduced",
            "largest link speeds " + " / ".join(num(x) for x in v.values()) + " rad/s, link "
            "angles up to " + " / ".join(num(x) for x in angle.values()) + " rad, "
            f"deflections up to {num(m.value('max_abs_deflection', prefix=pre))} rad, "
            f"fastest motor mode {num(m.value('motor_mode_max_rad_s', prefix=pre))} rad/s "
            f"(Nyquist {num(m.value('nyquist_rad_s'))}); stiffness MSE "
            + " / ".join(num(x) for x in s.values()), kind="diagnostic",
            metrics=[f"{pre}max_link_speed_joint{j}" for j in v]))
    got = [m.find(q, joint=j, prefix=p) for p in ("undamped_", "undamped_perturbed_")
           for q, j in (("stiffness_mse", 1), ("max_link_speed", 2))]
    if None not in got:
        (a, sp), (b, sp2) = (got[0].value, got[1].value), (got[2].value, got[3].value)
        change = abs(b - a) / abs(a) if a else float("inf")
        out.append(finding(
            "Section 6.2.3 as printed (no link damping): the undamped runaway is "
            "reproducible enough to compare with Table 6.1",
            "not reproduced" if change > 1e-3 else "reproduced",
            f"changing the torque amplitude by {num(m.value('undamped_perturbation'))} "
            f"(relative) moves the undamped stiffness MSE of joint 1 from {num(a)} to {num(b)} "
            f"(relative change {num(change)}) and the peak speed of link 2 from {num(sp)} to "
            f"{num(sp2)} rad/s: the runaway is chaotic, its indices are orders of magnitude "
            "only (threshold 1e-3 relative)", kind="diagnostic",
            metrics=[r.key for r in got]))
    return out


EXPERIMENT = Experiment(
    cost=8.3,  # CPU s, fresh-clone main job of 2026-12-06, load ~1
    id="ch6-electric-invasive",
    title="Invasive stiffness estimation, two-link arm with qbmove VSAs (Theorem 2 + RLS)",
    section="6.2.3, Fig. 6.5-6.6, Table 6.1",
    run=run,
    config=ElectricInvasiveConfig(),
    quick={"duration": 20.0},
    thesis=THESIS_ROWS,
    not_in_thesis=NOT_IN_THESIS,
    captions=CAPTIONS,
    findings=findings,
    discussion="""
**Reading.** The undamped run (`undamped_*`) is the thesis's model taken literally: the
open-loop torques exceed what gravity can hold, the links spin up
(`undamped_max_link_speed_joint*`), the spring deflections grow towards 1 rad
(`undamped_max_abs_deflection`) where the exponentially stiffening springs make the
motor modes (`undamped_motor_mode_max_rad_s`) faster than the Nyquist rate, and the
Euler-model observer (`undamped_observer_torque_mse_joint*`) fails there. With link
damping (headline) the links swing, the deflections stay small and the stiffness MSE
is of Table 6.1's order; `polynomial_fit_stiffness_msrep_joint*` bounds what the odd
polynomial model class can do. Compare the two `inputs_deflections_links.png` figures.
""",

)
