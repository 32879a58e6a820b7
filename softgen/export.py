"""``softgen export MODEL --out DIR``: a self-contained C project of a model's bundle.

The project holds the generated ``<model>.c``/``.h`` (copied, unchanged), a hand-written
runtime header (``softgen_rt.h``), typed wrappers emitted from the manifest
(``<model>_api.h``/``.c``: one struct per function with named, sized inputs and
outputs, work buffers sized at compile time, ``init``/``eval``/``free``), a
``Makefile`` and a ``CMakeLists.txt`` (C99, ``-O2``, ``-lm``) and a README. Models with
a shipped controller also get an example, ``main.c``, that runs it against the
generated plant step in a fixed-rate 1 kHz loop (``clock_nanosleep`` on an absolute
deadline) and reports tracking error, compute time and period jitter:

- Theorem 5 (``<model>_theorem5``) on McKibben bundles, σ from
  ``<model>_mckibben_torque`` at the pressures acting now, pressures clipped to
  [0, p_max], plant ``<model>_pneumatic_plant`` (what
  :func:`softgen.control.pneumatic_loop.closed_loop_fun` composes), gains and preset as
  :func:`softgen.experiments.ch10_pneumatic_adaptive.run_case`;
- Slotine–Li (``<model>_slotine_li``, Prop. 10) on the other rigid bundles, plant
  ``<model>_plant_rk4``, gains of the ``rigid-2link-adaptive`` experiment.

:func:`python_loop` runs the same loop with the bundle's casadi.Functions, so that the
C trajectory can be checked against CasADi's own evaluation (the test does, to
1e-12). The export is deterministic: the same model gives the same bytes.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import math
import re
import shlex
import shutil
import subprocess
import tempfile
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import BuildError, BundleError, SoftgenError

TEMPLATES = Path(__file__).parent / "export_templates"

#: Bumped whenever the exported files for the same bundle would change.
EXPORT_VERSION = "1"

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


# -- which bundle ------------------------------------------------------------------------

@contextlib.contextmanager
def bundle_files(model: str, generated_root: Path | None = None):
    """Yield ``(bundle_dir, manifest, note)`` for ``model``, generating it first if needed.

    A shipped model's bundle is read from ``generated_root`` (default: where ``softgen
    generate`` writes); when it is missing or stale (its model file, CasADi or the code
    generator changed, or its C source does not match the manifest) it is generated
    again there, or in a temporary directory when that is not writable. A model file
    given by path is always generated in a temporary directory. ``note`` says which
    (empty when the bundle was current).
    """
    from .bundle import check_model_unchanged, generate
    from .codegen.build import check_source, read_manifest
    from .model import MODELS_DIR, load_model, model_path
    from .paths import GENERATED_DIR, writable

    path = model_path(model)            # one ModelError line for an unknown name
    root = Path(generated_root or GENERATED_DIR)
    shipped = path.resolve().parent == MODELS_DIR.resolve()
    why = f"{path} is not a shipped model"
    if shipped:
        bundle = root / path.stem
        try:
            manifest = read_manifest(bundle)
            check_source(bundle, manifest)
            check_model_unchanged(manifest, bundle)
            why = ""
        except BundleError as exc:
            why = str(exc).splitlines()[0]
        if not why:      # current: outside the try, so the caller's errors pass through
            yield bundle, manifest, ""
            return
        if writable(root):
            bundle = generate(path.stem, root)
            yield bundle, read_manifest(bundle), f"regenerated {bundle} ({why})"
            return
    with tempfile.TemporaryDirectory(prefix="softgen-export-") as tmp:
        name = load_model(path).name
        bundle = generate(path, Path(tmp))
        yield bundle, read_manifest(bundle), f"generated {name} in a temporary directory ({why})"


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
        from .experiments.rigid_2link_adaptive import RigidAdaptiveConfig
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
        from .bundle import model_file_path
        from .experiments.ch10_pneumatic_adaptive import Ch10AdaptiveConfig
        from .model import load_model
        from .symbolic.actuators import McKibbenPairs
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


def python_loop(model: str, steps: int = 1000, *,
                generated_root: Path | None = None) -> tuple[list[str], np.ndarray]:
    """The example loop of ``softgen export MODEL`` run with CasADi in Python.

    Same functions (rebuilt from the model file, :func:`softgen.bundle.casadi_functions`),
    same configuration and same order of operations as the exported ``main.c``; returns
    ``(columns, rows)``, one row per sample as its ``--csv`` writes them.
    """
    from .bundle import casadi_functions
    with bundle_files(model, generated_root) as (_, manifest, _):
        cfg = example_config(manifest)
        if cfg is None:
            raise SoftgenError(f"{manifest['model']}: no example loop ({_no_example(manifest)})")
        functions = casadi_functions(manifest)
    return cfg.columns, run_python_loop(cfg, functions, steps)


def _no_example(manifest: dict) -> str:
    m = manifest["model"]
    return f"the bundle has neither {m}_theorem5 nor {m}_slotine_li with {m}_plant_rk4"


# -- rendering ---------------------------------------------------------------------------

def _template(name: str, values: dict[str, str], example: bool) -> str:
    """Template ``name`` with ``@KEY@`` replaced and the ``@IF_EXAMPLE@ … @ELSE@ … @END@``
    line blocks (and ``@IF_EXAMPLE_INLINE@ … @END_INLINE@`` spans) kept or dropped."""
    text = (TEMPLATES / name).read_text()
    text = re.sub(r"@IF_EXAMPLE_INLINE@(.*?)@END_INLINE@", lambda mt: mt[1] if example else "",
                  text, flags=re.S)
    out, keep = [], [True]
    for line in text.splitlines(keepends=True):
        tag = line.strip()
        if tag == "@IF_EXAMPLE@":
            keep.append(example)
        elif tag == "@ELSE@":
            keep[-1] = not keep[-1]
        elif tag == "@END@":
            keep.pop()
        elif all(keep):
            out.append(line)
    text = "".join(out)
    for key, value in values.items():
        text = text.replace(f"@{key}@", value)
    left = sorted(set(re.findall(r"@[A-Z_]+@", text)))
    if left:
        raise RuntimeError(f"export template {name}: unfilled placeholders {left}")
    return text


_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto if "
    "inline int long register restrict return short signed sizeof static struct switch "
    "typedef union unsigned void volatile while in out".split())


def _members(signals: list[dict]) -> list[tuple[str, str, int, int]]:
    """(C member name, original name, rows, cols) of a function's inputs or outputs."""
    out, seen = [], set()
    for s in signals:
        name = re.sub(r"\W", "_", s["name"]) or "x"
        if name[0].isdigit() or name in _C_KEYWORDS:
            name = f"{name}_"
        base, i = name, 2
        while name in seen:
            name, i = f"{base}_{i}", i + 1
        seen.add(name)
        out.append((name, s["name"], int(s["shape"][0]), int(s["shape"][1])))
    return out


def _c_comment(text: str) -> str:
    return text.replace("*/", "* /")


def _api_header(manifest: dict, h_src: str) -> str:
    m = manifest["model"]
    guard = f"{m.upper()}_API_H"
    lines = [f"/* {m}_api.h: typed wrappers of the functions generated for {m}.",
             " *",
             " * Written by `softgen export` from manifest.json. Per function <f>: a struct <f>_t",
             " * with the inputs in `in` and the outputs in `out` (dense, column-major), work",
             " * buffers sized by the generated <f>_SZ_* macros, and <f>_init, <f>_eval,",
             " * <f>_free (softgen_rt.h). Keep the structs static or global: they hold the",
             " * work buffers, which can be large.",
             " */",
             f"#ifndef {guard}", f"#define {guard}", "",
             f'#include "{m}.h"', '#include "softgen_rt.h"', "",
             "#ifdef __cplusplus", 'extern "C" {', "#endif", "",
             f"#define {m.upper()}_API_N_FUNCTIONS {len(manifest['functions'])}", ""]
    for f, sig in manifest["functions"].items():
        for sz in ("ARG", "RES", "IW", "W"):
            if not re.search(rf"^#define {re.escape(f)}_SZ_{sz} \d+$", h_src, re.M):
                raise BundleError(f"{m}/{m}.h: no #define {f}_SZ_{sz}; regenerate the bundle")
        lines += [f"/* {f}: {_c_comment(sig.get('doc', ''))} */", "typedef struct {"]
        for part, key in (("in", "inputs"), ("out", "outputs")):
            members = _members(sig[key])
            if not members:
                lines.append(f"  struct {{ casadi_real unused_; }} {part};   /* none */")
                continue
            lines.append("  struct {")
            for name, orig, r, c in members:
                note = f"{r} x {c}" + (f", '{orig}'" if name != orig else "")
                lines.append(f"    casadi_real {name}[{max(r * c, 1)}];   /* {note} */")
            lines.append(f"  }} {part};")
        lines += [f"  const casadi_real *arg[SOFTGEN_RT_DIM({f}_SZ_ARG)];",
                  f"  casadi_real *res[SOFTGEN_RT_DIM({f}_SZ_RES)];",
                  f"  casadi_int iw[SOFTGEN_RT_DIM({f}_SZ_IW)];",
                  f"  casadi_real w[SOFTGEN_RT_DIM({f}_SZ_W)];",
                  "  int mem;     /* CasADi memory of _checkout */",
                  "  int ready;   /* 1 from a successful init to free */",
                  f"}} {f}_t;",
                  f"int {f}_init({f}_t *f);",
                  f"int {f}_eval({f}_t *f);",
                  f"void {f}_free({f}_t *f);", ""]
    lines += ["/* Initialise and release the wrapper of every function above: SOFTGEN_RT_OK, or",
              "   the first error with *failed set to the function's name. *count: how many",
              "   succeeded. */",
              f"int {m}_api_check_all(const char **failed, int *count);", "",
              "#ifdef __cplusplus", '} /* extern "C" */', "#endif", "",
              f"#endif /* {guard} */", ""]
    return "\n".join(lines)


def _api_source(manifest: dict) -> str:
    m = manifest["model"]
    lines = [f"/* {m}_api.c: typed wrappers of the functions generated for {m} (see {m}_api.h).",
             " * Written by `softgen export` from manifest.json. */",
             "#include <string.h>", "", f'#include "{m}_api.h"', ""]
    check = []
    for f, sig in manifest["functions"].items():
        ins, outs = _members(sig["inputs"]), _members(sig["outputs"])
        shape = lambda ms: ", ".join(f"{r}, {c}" for _, _, r, c in ms) or "0"   # noqa: E731
        lines += [f"/* {f} */",
                  f"static const casadi_int {f}_shape_in[] = {{{shape(ins)}}};",
                  f"static const casadi_int {f}_shape_out[] = {{{shape(outs)}}};",
                  f"static const softgen_rt_desc {f}_desc = {{",
                  f'  "{f}", {len(ins)}, {len(outs)}, {f}_shape_in, {f}_shape_out,',
                  f"  {f}_n_in, {f}_n_out, {f}_work, {f}_sparsity_in, {f}_sparsity_out,",
                  f"  {f}_checkout, {f}_release, {f}_incref, {f}_decref}};", "",
                  f"int {f}_init({f}_t *f) {{",
                  "  memset(f, 0, sizeof *f);",
                  f"  return softgen_rt_init(&{f}_desc, &f->mem, &f->ready, "
                  f"SOFTGEN_RT_DIM({f}_SZ_ARG),",
                  f"                         SOFTGEN_RT_DIM({f}_SZ_RES), "
                  f"SOFTGEN_RT_DIM({f}_SZ_IW), SOFTGEN_RT_DIM({f}_SZ_W));",
                  "}", "",
                  f"int {f}_eval({f}_t *f) {{",
                  "  if (!f->ready) return SOFTGEN_RT_ENOTREADY;",
                  "  /* Set every call: the struct may have been copied since init. */"]
        lines += [f"  f->arg[{i}] = f->in.{name};" for i, (name, *_) in enumerate(ins)]
        lines += [f"  f->res[{i}] = f->out.{name};" for i, (name, *_) in enumerate(outs)]
        lines += [f"  return {f}(f->arg, f->res, f->iw, f->w, f->mem) ? SOFTGEN_RT_EEVAL "
                  ": SOFTGEN_RT_OK;", "}", "",
                  f"void {f}_free({f}_t *f) {{ softgen_rt_free(&{f}_desc, &f->mem, &f->ready); }}",
                  ""]
        check += ["  {", f"    static {f}_t s;", f"    if ((rc = {f}_init(&s))) {{",
                  f'      *failed = "{f}";', "      return rc;", "    }",
                  f"    {f}_free(&s);", "    ++*count;", "  }"]
    lines += [f"int {m}_api_check_all(const char **failed, int *count) {{", "  int rc;",
              "  *count = 0;", *check, "  return SOFTGEN_RT_OK;", "}", ""]
    return "\n".join(lines)


def _c_double(v: float) -> str:
    """An exact C literal of ``v`` (Python's repr round-trips; infinity is HUGE_VAL)."""
    v = float(v)
    if math.isinf(v):
        return "HUGE_VAL" if v > 0 else "-HUGE_VAL"
    if math.isnan(v):
        raise ValueError("example configuration: NaN has no place in example_config.h")
    text = repr(v)
    return text if any(ch in text for ch in ".en") else text + ".0"


def _config_header(cfg: ExampleConfig, manifest: dict) -> str:
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
                            f"Values are exact doubles. Sources: {_c_comment(cfg.source)}.",
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


def _example_text(cfg: ExampleConfig) -> str:
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


def render(manifest: dict, c_src: bytes, h_src: bytes, manifest_bytes: bytes) -> dict[str, bytes]:
    """The exported project's files (name -> bytes); a function of the bundle only."""
    m = manifest["model"]
    cfg = example_config(manifest)
    example = cfg is not None
    files = {f"{m}.c": c_src, f"{m}.h": h_src,
             "manifest.json": manifest_bytes,
             "softgen_rt.h": (TEMPLATES / "softgen_rt.h").read_bytes(),
             f"{m}_api.h": _api_header(manifest, h_src.decode()).encode(),
             f"{m}_api.c": _api_source(manifest).encode()}
    title = ("Theorem 5 on the McKibben arm" if cfg and cfg.kind == "theorem5" else
             "Slotine-Li (Prop. 10) on the rigid arm")
    values = {"MODEL": m, "EXAMPLE_TITLE": title}
    if example:
        files["softgen_loop.h"] = (TEMPLATES / "softgen_loop.h").read_bytes()
        files["main.c"] = _template(f"main_{cfg.kind}.c", values, example).encode()
        files["example_config.h"] = _config_header(cfg, manifest).encode()
    files["Makefile"] = _template("Makefile.in", values, example).encode()
    files["CMakeLists.txt"] = _template("CMakeLists.txt.in", values, example).encode()
    table = "\n".join(f"- `{f}`: {s.get('doc', '')}" for f, s in manifest["functions"].items())
    files["README.md"] = _template("README.md.in", {
        **values, "MODEL_FILE": manifest.get("model_file", m),
        "HASH": manifest["hash"][:16], "CASADI_VERSION": manifest.get("casadi_version", "?"),
        "EXAMPLE_TEXT": _example_text(cfg) if example else "",
        "NO_EXAMPLE_TEXT": f"No example loop exists for {m}: {_no_example(manifest)}." if
        not example else "",
        "FUNCTIONS": table}, example).encode()
    record = {"model": m, "bundle_hash": manifest["hash"], "export_version": EXPORT_VERSION,
              "example": cfg.kind if example else None,
              "files": {k: hashlib.sha256(v).hexdigest() for k, v in sorted(files.items())}}
    files[RECORD] = (json.dumps(record, indent=2) + "\n").encode()
    return files


#: What an export writes about itself: its files and their sha256 (used by --force).
RECORD = "softgen_export.json"


# -- writing and building ----------------------------------------------------------------

@dataclass
class ExportResult:
    """What :func:`export` did."""

    out: Path
    model: str
    files: list[str]
    example: str | None          # "theorem5", "slotine_li" or None
    note: str                    # bundle regenerated? ("" if it was current)
    build_seconds: float | None = None
    binary: Path | None = None


def _check_out_dir(out: Path, force: bool) -> None:
    import os
    if out.exists() and not out.is_dir():
        raise SoftgenError(f"--out {out}: exists and is not a directory; give a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise SoftgenError(f"--out {out}: exists and is not empty; give a new or empty "
                           "directory, or --force to overwrite the exported files")
    base = out
    while not base.exists():
        base = base.parent
    if not os.access(base, os.W_OK | os.X_OK):
        raise SoftgenError(f"--out {out}: {base} is not writable")


def export(model: str, out: Path | str, *, force: bool = False, build: bool = False,
           cc: str | None = None, generated_root: Path | None = None) -> ExportResult:
    """Write the C project of ``model``'s bundle to ``out`` (see the module docstring).

    ``out`` must be new or empty unless ``force`` (then the files of the export are
    overwritten, and those a previous export listed in ``softgen_export.json`` but this
    one does not write are removed; nothing else is touched). ``build`` compiles the
    project with the Makefile (``make CC=<compiler>``; without make, the same commands
    directly) and fails with one line if there is no C compiler.
    """
    from .codegen.build import find_compiler
    out = Path(out)
    _check_out_dir(out, force)
    compiler = None
    if build:
        compiler = find_compiler(cc)
        if compiler is None:
            raise SoftgenError("--build: no C compiler found" + (f" ({cc or 'CC'} not on PATH)"
                               if cc else "") + "; install gcc or clang, set CC, or drop --build")
    with bundle_files(model, generated_root) as (bundle, manifest, note):
        m = manifest["model"]
        files = render(manifest, *((bundle / f).read_bytes() for f in
                                   (f"{m}.c", f"{m}.h", "manifest.json")))
    out.mkdir(parents=True, exist_ok=True)
    old = out / RECORD
    if force and old.is_file():
        try:
            previous = json.loads(old.read_text()).get("files", {})
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
            previous = {}
        for name in previous:
            if name not in files and "/" not in name and (out / name).is_file():
                (out / name).unlink()
    for name, data in files.items():
        (out / name).write_bytes(data)
    res = ExportResult(out=out, model=m, files=sorted(files), example=example_kind(manifest),
                       note=note)
    if build:
        res.build_seconds, res.binary = build_project(out, m, compiler, res.example is not None)
    return res


def build_project(out: Path, model: str, compiler: str, example: bool) -> tuple[float, Path | None]:
    """Build an exported project with its Makefile; return (seconds, example binary or None)."""
    make = shutil.which("make")
    t0 = time.perf_counter()
    if make:
        cmds = [[make, "-C", str(out), f"CC={compiler}"]]
    else:   # the Makefile's commands, without make
        flags = [compiler, "-std=c99", "-ffp-contract=off", "-O2"]
        objs = [f"{model}.o", f"{model}_api.o"] + (["main.o"] if example else [])
        cmds = [[*flags, "-c", "-o", o, o[:-2] + ".c"] for o in objs]
        if example:
            cmds.append([*flags, "-o", f"{model}_example", *objs, "-lm"])
    for cmd in cmds:
        proc = subprocess.run(cmd, cwd=out, capture_output=True, text=True)
        if proc.returncode != 0:
            raise BuildError(f"building {out} failed ({shlex.join(cmd)})",
                             proc.stderr[-4000:])
    binary = out / f"{model}_example"
    return time.perf_counter() - t0, binary if example else None


def summary(res: ExportResult) -> list[str]:
    """The lines ``softgen export`` prints: where things went and how to build and run."""
    o = shlex.quote(str(res.out))
    lines = [f"softgen export: {res.note}"] if res.note else []
    lines.append(f"wrote {len(res.files)} files to {res.out}: {', '.join(res.files)}")
    if res.example is None:
        lines.append(f"no example loop for {res.model}: it has neither {res.model}_theorem5 nor "
                     f"{res.model}_slotine_li; exported the library, wrappers and build files")
    lines += [f"build: make -C {o}",
              f"   or: cmake -S {o} -B {o}/build && cmake --build {o}/build"]
    if res.build_seconds is not None:
        lines.append(f"built with make in {res.build_seconds:.1f} s")
    if res.example is not None:
        what = "Theorem 5" if res.example == "theorem5" else "Slotine-Li (Prop. 10)"
        lines.append(f"run:   {o}/{res.model}_example [--fast] [--steps N | --seconds S] "
                     f"[--csv FILE] [--rt]   ({what}, 1 kHz; see {o}/README.md)")
    return lines
