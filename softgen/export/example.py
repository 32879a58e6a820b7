"""The example loop of ``softgen export``: its configuration and its Python/CasADi twin.

:class:`ExampleConfig` holds what ``example_config.h`` bakes into the exported
``main.c`` (gains, initial state, sinusoidal references) and what
:func:`run_python_loop` uses to run the same loop with the bundle's casadi.Functions:
the same functions, the same constants (written as exact doubles) and the same order
of floating-point operations, so the two trajectories agree to rounding.
"""
from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass

import numpy as np

from softgen.core.errors import BundleError, SoftgenError

#: Seconds of the example's default run (at the bundle's sample time).
DEFAULT_SECONDS = 10.0

#: Theorem 5 example reference (section 10.2 gives phases, not values): position steps
#: of 0-0.3 rad and stiffnesses of 2-4 N m/rad as in ch10-pneumatic-adaptive, here as
#: smooth sinusoids. q_d,i = a (1 - cos 2π f_i t); σ_d,i = σ0 + a_σ sin(2π f_σ,i t).
T5_Q_AMPLITUDE = 0.15            # rad
T5_Q_FREQUENCY = (0.2, 0.3)      # Hz, cycled over the joints
T5_SIGMA_OFFSET = 3.0            # N m/rad
T5_SIGMA_AMPLITUDE = 1.0         # N m/rad
T5_SIGMA_FREQUENCY = (0.1, 0.15)  # Hz, cycled over the joints


# -- the example's configuration -----------------------------------------------------------

@dataclass(frozen=True)
class ExampleConfig:
    """Gains, initial state and reference of the example loop (``example_config.h``).

    ``kind`` is ``"theorem5"`` or ``"slotine_li"``. The reference of joint i is
    q_d,i = offset + amplitude sin(omega t + phase) with analytic derivatives; for
    Theorem 5 also σ_d,i = sigma_offset + sigma_amplitude sin(sigma_omega t + sigma_phase).
    """

    kind: str
    model: str
    n: int
    n_params: int
    dt: float
    x0: tuple[float, ...]
    lam: tuple[float, ...]
    kd: tuple[float, ...]
    kpi: tuple[float, ...]
    pi_hat0: tuple[float, ...]
    ref_offset: tuple[float, ...]
    ref_amplitude: tuple[float, ...]
    ref_omega: tuple[float, ...]
    ref_phase: tuple[float, ...]
    sigma_offset: tuple[float, ...] = ()
    sigma_amplitude: tuple[float, ...] = ()
    sigma_omega: tuple[float, ...] = ()
    sigma_phase: tuple[float, ...] = ()
    ksigma: tuple[float, ...] = ()
    kinv: tuple[float, ...] = ()
    p_max: tuple[float, ...] = ()
    source: str = ""

    @property
    def default_steps(self) -> int:
        return int(round(DEFAULT_SECONDS / self.dt))

    @property
    def functions(self) -> dict[str, str]:
        """Role -> generated function the example calls."""
        m = self.model
        if self.kind == "theorem5":
            return {"controller": f"{m}_theorem5", "preset": f"{m}_open_loop_stiffness",
                    "stiffness": f"{m}_mckibben_torque", "plant": f"{m}_pneumatic_plant"}
        return {"controller": f"{m}_slotine_li", "plant": f"{m}_plant_rk4"}

    @property
    def columns(self) -> list[str]:
        """The CSV columns of the example (and of :func:`python_loop`)."""
        n, p = self.n, self.n_params
        j = lambda s, k=n: [f"{s}{i + 1}" for i in range(k)]   # noqa: E731
        head = ["k", "t", *j("q"), *j("qd"), *j("q_d")]
        if self.kind == "theorem5":
            return head + j("sigma") + j("sigma_d") + j("nu") + j("Pi_hat", p) + j("p_cmd", 2 * n)
        return head + j("pi_hat", p) + j("tau")


def _cycle(values, n: int) -> tuple[float, ...]:
    return tuple(float(values[i % len(values)]) for i in range(n))


def example_kind(manifest: dict) -> str | None:
    """``"theorem5"``, ``"slotine_li"`` or None: which example loop the bundle supports."""
    m, fns = manifest["model"], manifest["functions"]
    if f"{m}_theorem5" in fns and "controllers" in manifest:
        return "theorem5"
    if f"{m}_slotine_li" in fns and f"{m}_plant_rk4" in fns:
        return "slotine_li"
    return None


def example_config(manifest: dict) -> ExampleConfig | None:
    """The example's configuration for the bundle of ``manifest`` (None: no example)."""
    kind = example_kind(manifest)
    if kind is None:
        return None
    m, n = manifest["model"], int(manifest["dof"])
    if kind == "slotine_li":
        from softgen.experiments.rigid_2link_adaptive import RigidAdaptiveConfig
        c = RigidAdaptiveConfig()
        p = len(manifest["parameters"]["names"])
        cfg = ExampleConfig(
            kind=kind, model=m, n=n, n_params=p, dt=float(c.dt),
            x0=_cycle(c.offset, n) + (0.0,) * n,        # on the reference at t = 0
            lam=_cycle(c.lam, n), kd=_cycle(c.kd, n), kpi=_cycle(c.kpi, p),
            pi_hat0=_cycle(c.pi_hat0, p),
            ref_offset=_cycle(c.offset, n), ref_amplitude=_cycle(c.amplitude, n),
            ref_omega=tuple(2 * math.pi * f for f in _cycle(c.frequency, n)),
            ref_phase=(0.0,) * n,
            source="gains, pi_hat(0) = 0 and sinusoids of the rigid-2link-adaptive experiment "
                   "(softgen/experiments/rigid_2link_adaptive.py), cycled over the joints")
    else:
        from softgen.bundles.bundle import model_file_path
        from softgen.experiments.ch10_pneumatic_adaptive import Ch10AdaptiveConfig
        from softgen.modelfile.model import load_model
        from softgen.symbolic.actuators import McKibbenPairs
        c = Ch10AdaptiveConfig()
        ctl = manifest["controllers"]
        Pi, K1 = [float(v) for v in ctl["Pi_nominal"]], float(ctl["K1"])
        act = McKibbenPairs(load_model(model_file_path(manifest)))
        a = T5_Q_AMPLITUDE
        cfg = ExampleConfig(
            kind=kind, model=m, n=n, n_params=len(Pi), dt=float(c.dt),
            x0=(0.0,) * (2 * n),
            lam=(float(c.lam),) * n, kd=(float(c.kd),) * n, kpi=(float(c.kpi),) * len(Pi),
            pi_hat0=tuple(c.pi_hat0_ratio * v for v in Pi),
            ref_offset=(a,) * n, ref_amplitude=(a,) * n,
            ref_omega=tuple(2 * math.pi * f for f in _cycle(T5_Q_FREQUENCY, n)),
            ref_phase=(-math.pi / 2,) * n,
            sigma_offset=(T5_SIGMA_OFFSET,) * n, sigma_amplitude=(T5_SIGMA_AMPLITUDE,) * n,
            sigma_omega=tuple(2 * math.pi * f for f in _cycle(T5_SIGMA_FREQUENCY, n)),
            sigma_phase=(0.0,) * n,
            ksigma=(c.stiffness_rate / K1,) * n,
            kinv=tuple(float(1 / k) for k in act.K),
            p_max=tuple(float(v) for v in np.repeat(act.pressure_max, 2)),
            source="gains of ch10-pneumatic-adaptive (K_d = 18, lambda = 15, K_pi = 35, "
                   "K_sigma = rate/K1 with rate 2 1/s, kinv = 1/K, Pi_hat(0) = 0.9 Pi; "
                   "softgen/experiments/ch10_pneumatic_adaptive.py), nu and p preset by the "
                   "open-loop stiffness step; sinusoidal references of softgen/export.py")
    _check_signatures(manifest, cfg)
    return cfg


def _check_signatures(manifest: dict, cfg: ExampleConfig) -> None:
    """The example's functions have the inputs and outputs main.c assumes (else one line)."""
    n, p = cfg.n, cfg.n_params
    v = lambda k: [k, 1]   # noqa: E731
    if cfg.kind == "theorem5":
        gains = [("lam", v(n)), ("kd", v(n)), ("kpi", v(p))]
        want = {
            "controller": ([("z", v(n + p)), ("q", v(n)), ("qd", v(n)), ("sigma", v(n)),
                            ("ref", v(6 * n)), *gains, ("ksigma", v(n)), ("kinv", v(n)),
                            ("dt", v(1))],
                           [("z_next", v(n + p)), ("p", v(2 * n)), ("tau_star", v(n)),
                            ("nu", v(n))]),
            "preset": ([("z", v(p)), ("q", v(n)), ("qd", v(n)), ("ref", v(6 * n)), *gains,
                        ("kinv", v(n)), ("dt", v(1))],
                       [("z_next", v(p)), ("p", v(2 * n)), ("tau_star", v(n)), ("nu", v(n))]),
            "stiffness": ([("q", v(n)), ("p", v(2 * n))], [("tau", v(n)), ("sigma", v(n))]),
            "plant": ([("x", v(2 * n)), ("p", v(2 * n)), ("h", v(1))], [("x_next", v(2 * n))]),
        }
    else:
        want = {
            "controller": ([("pi_hat", v(p)), *((s, v(n)) for s in
                                                ("q", "qd", "q_d", "qd_d", "qdd_d", "lam", "kd")),
                            ("kpi", v(p)), ("dt", v(1))],
                           [("pi_hat_next", v(p)), ("tau", v(n))]),
            "plant": ([("x", v(2 * n)), ("tau", v(n)), ("h", v(1))], [("x_next", v(2 * n))]),
        }
    for role, (ins, outs) in want.items():
        name = cfg.functions[role]
        f = manifest["functions"].get(name)
        got = None if f is None else (
            [(s["name"], list(s["shape"])) for s in f["inputs"]],
            [(s["name"], list(s["shape"])) for s in f["outputs"]])
        if got != ([(a, list(b)) for a, b in ins], [(a, list(b)) for a, b in outs]):
            raise BundleError(f"{manifest['model']}/manifest.json: functions.{name}: expected "
                              f"inputs {[a for a, _ in ins]} and outputs {[a for a, _ in outs]} "
                              f"with the example's shapes, got "
                              f"{'nothing' if got is None else [[a for a, _ in g] for g in got]}")


# -- the Python/CasADi loop --------------------------------------------------------------

def _reference(cfg: ExampleConfig, t: float) -> list[list[float]]:
    """(q_d, qd_d, qdd_d, qddd_d, sigma_d, sigmad_d) at t, operation for operation as
    ``reference()`` in main.c (scalar libm sin/cos, same order), so the two agree exactly."""
    out = [[], [], [], [], [], []]
    for i in range(cfg.n):
        a, w = cfg.ref_amplitude[i], cfg.ref_omega[i]
        arg = w * t + cfg.ref_phase[i]
        s, c = math.sin(arg), math.cos(arg)
        out[0].append(cfg.ref_offset[i] + a * s)
        out[1].append(a * w * c)
        out[2].append(-a * w * w * s)
        out[3].append(-a * w * w * w * c)
        if cfg.kind == "theorem5":
            sa, sw = cfg.sigma_amplitude[i], cfg.sigma_omega[i]
            args = sw * t + cfg.sigma_phase[i]
            out[4].append(cfg.sigma_offset[i] + sa * math.sin(args))
            out[5].append(sa * sw * math.cos(args))
    return out


def _clip(v: float, hi: float) -> float:
    return min(max(v, 0.0), hi)


def run_python_loop(cfg: ExampleConfig, functions: dict, steps: int) -> np.ndarray:
    """``steps`` samples of the example loop with the casadi.Functions ``functions``
    (name -> Function); rows as the example's ``--csv`` (:attr:`ExampleConfig.columns`)."""
    if not (isinstance(steps, int) and steps >= 1):
        raise SoftgenError(f"steps: expected a positive integer, got {steps!r}")
    fn = {role: functions[name] for role, name in cfg.functions.items()}
    flat = lambda v: np.asarray(v, dtype=float).ravel()   # noqa: E731
    n, dt = cfg.n, cfg.dt
    rows = np.empty((steps, len(cfg.columns)))
    x = np.array(cfg.x0, dtype=float)
    if cfg.kind == "slotine_li":
        pi_hat = np.array(cfg.pi_hat0, dtype=float)
        for k in range(steps):
            t = k * dt
            q_d, qd_d, qdd_d, *_ = _reference(cfg, t)
            pi_next, tau = (flat(o) for o in fn["controller"](
                pi_hat, x[:n], x[n:], q_d, qd_d, qdd_d, cfg.lam, cfg.kd, cfg.kpi, dt))
            rows[k] = [k, t, *x, *q_d, *pi_hat, *tau]
            x = flat(fn["plant"](x, tau, dt))
            pi_hat = pi_next
        return rows
    # Theorem 5: preset nu and p by the open-loop stiffness step (K_pi = 0) at x0.
    ref0 = [v for block in _reference(cfg, 0.0) for v in block]
    _, p0, _, nu0 = (flat(o) for o in fn["preset"](
        cfg.pi_hat0, x[:n], x[n:], ref0, cfg.lam, cfg.kd, np.zeros(cfg.n_params), cfg.kinv, dt))
    z = np.concatenate([nu0, cfg.pi_hat0])
    p = np.array([_clip(v, hi) for v, hi in zip(p0, cfg.p_max)])
    for k in range(steps):
        t = k * dt
        ref = _reference(cfg, t)
        sigma = flat(fn["stiffness"](x[:n], p)[1])
        z_next, p_cmd, _, _ = (flat(o) for o in fn["controller"](
            z, x[:n], x[n:], sigma, [v for block in ref for v in block], cfg.lam, cfg.kd,
            cfg.kpi, cfg.ksigma, cfg.kinv, dt))
        rows[k] = [k, t, *x, *ref[0], *sigma, *ref[4], *z, *p_cmd]
        p = np.array([_clip(v, hi) for v, hi in zip(p_cmd, cfg.p_max)])
        x = flat(fn["plant"](x, p, dt))
        z = z_next
    return rows


def no_example(manifest: dict) -> str:
    """Why the bundle of ``manifest`` has no example loop."""
    m = manifest["model"]
    return f"the bundle has neither {m}_theorem5 nor {m}_slotine_li with {m}_plant_rk4"


# -- example_config.h and the README's paragraph ------------------------------------------

def c_comment(text: str) -> str:
    """``text`` safe inside a C comment."""
    return text.replace("*/", "* /")


def _c_double(v: float) -> str:
    """An exact C literal of ``v`` (Python's repr round-trips; infinity is HUGE_VAL)."""
    v = float(v)
    if math.isinf(v):
        return "HUGE_VAL" if v > 0 else "-HUGE_VAL"
    if math.isnan(v):
        raise ValueError("example configuration: NaN has no place in example_config.h")
    text = repr(v)
    return text if any(ch in text for ch in ".en") else text + ".0"


def config_header(cfg: ExampleConfig, manifest: dict) -> str:
    m = cfg.model
    arr = lambda vals: "{" + ", ".join(_c_double(v) for v in vals) + "}"   # noqa: E731
    rows = [("EX_X0", "2 * EX_N", cfg.x0, "q(0), qd(0)"),
            ("EX_LAM", "EX_N", cfg.lam, "lambda"),
            ("EX_KD", "EX_N", cfg.kd, "K_d"),
            ("EX_KPI", "EX_NP", cfg.kpi, "K_pi (adaptation gains)"),
            ("EX_PI_HAT0", "EX_NP", cfg.pi_hat0,
             "Pi_hat(0)" if cfg.kind == "theorem5" else "pi_hat(0)"),
            ("EX_REF_OFFSET", "EX_N", cfg.ref_offset, "q_d = offset + amplitude sin(omega t"
                                                       " + phase), rad"),
            ("EX_REF_AMPLITUDE", "EX_N", cfg.ref_amplitude, "rad"),
            ("EX_REF_OMEGA", "EX_N", cfg.ref_omega, "rad/s"),
            ("EX_REF_PHASE", "EX_N", cfg.ref_phase, "rad")]
    if cfg.kind == "theorem5":
        rows += [("EX_SIGMA_OFFSET", "EX_N", cfg.sigma_offset,
                  "sigma_d = offset + amplitude sin(omega t + phase), N m/rad"),
                 ("EX_SIGMA_AMPLITUDE", "EX_N", cfg.sigma_amplitude, "N m/rad"),
                 ("EX_SIGMA_OMEGA", "EX_N", cfg.sigma_omega, "rad/s"),
                 ("EX_SIGMA_PHASE", "EX_N", cfg.sigma_phase, "rad"),
                 ("EX_KSIGMA", "EX_N", cfg.ksigma, "K_sigma"),
                 ("EX_KINV", "EX_N", cfg.kinv, "K^-1 of each joint's muscles"),
                 ("EX_P_MAX", "2 * EX_N", cfg.p_max, "pressure limits, Pa")]
    lines = [f"/* example_config.h: gains, initial state and reference of the {m} example.",
             " *",
             *textwrap.wrap(f"Written by `softgen export` (bundle hash {manifest['hash'][:16]}). "
                            f"Values are exact doubles. Sources: {c_comment(cfg.source)}.",
                            86, initial_indent=" * ", subsequent_indent=" * "),
             " */",
             "#ifndef EXAMPLE_CONFIG_H", "#define EXAMPLE_CONFIG_H", "",
             "#include <math.h>", "",
             f"#define EX_N {cfg.n}          /* joints */",
             f"#define EX_NP {cfg.n_params}         /* adapted parameters */",
             f"#define EX_DT {_c_double(cfg.dt)}     /* sample time, s */",
             f"#define EX_DEFAULT_STEPS {cfg.default_steps}L   /* {DEFAULT_SECONDS:g} s */",
             f"#define EX_NCOL {len(cfg.columns)}      /* CSV columns */", ""]
    for name, size, vals, note in rows:
        lines += [f"/* {note} */", f"static const double {name}[{size}] = {arr(vals)};"]
    cols = ", ".join(f'"{c}"' for c in cfg.columns)
    lines += ["", "/* CSV header: sample, time, then the signals of main.c's row. */",
              f"static const char *const EX_COLUMNS[EX_NCOL] = {{{cols}}};", "",
              "#endif /* EXAMPLE_CONFIG_H */", ""]
    return "\n".join(lines)


def example_text(cfg: ExampleConfig) -> str:
    return textwrap.fill(_example_paragraph(cfg), 88)


def _example_paragraph(cfg: ExampleConfig) -> str:
    f = cfg.functions
    if cfg.kind == "theorem5":
        return (f"The example runs Theorem 5 (decoupled adaptive position and stiffness "
                f"control, thesis section 10.2; `{f['controller']}`) against the McKibben "
                f"arm with pressures applied as commanded, clipped to [0, p_max] "
                f"(`{f['plant']}`), reading the stiffness σ of the pressures acting at each "
                f"sample (`{f['stiffness']}`). ν and the pressures start from the open-loop "
                f"stiffness step (`{f['preset']}`, K_π = 0) at rest, the thesis's "
                f"\"initially inflated\" preset. References: q_d,i = a(1 − cos ω_i t), "
                f"σ_d,i = σ0 + a_σ sin(ω_σ,i t), derivatives analytic. It reports the "
                f"position and stiffness tracking errors and how many pressure commands were "
                f"clipped. Gains and references: `example_config.h`.")
    return (f"The example runs Slotine–Li adaptive control (thesis Prop. 10, "
            f"`{f['controller']}`, every parameter unknown at the start) against the nominal "
            f"arm (`{f['plant']}`, one RK4 step per sample, torque held), tracking sinusoids "
            f"with analytic derivatives. Gains and references: `example_config.h`.")
