"""``softgen observer``: a delayed unknown-input observer for the user's own system.

The system is the discrete linear plant of eq. 5.1, ``X_{k+1} = A X_k + B U_k``,
``Y_k = C X_k + D U_k``, whose inputs are split into *unknown* ones (reconstructed by
the observer) and *known* ones (fed to it). It comes either from a file
(:func:`read_system`, TOML or JSON) or from a model's linearisation
(:func:`linearise_model`: the plant's one-sample step function differentiated by
CasADi about an operating point). :func:`check_system` evaluates the existence
conditions of Props. 7-9 (eq. 5.3; :func:`softgen.estimation.uio.existence_conditions`)
for the requested delay and finds the smallest delay that works;
:func:`write_observer` emits the observer's step as generated C with a manifest that
records every matrix.

System file (TOML or JSON, the same keys; ``.toml`` or ``.json``)
-----------------------------------------------------------------
``A``, ``B``, ``C``, ``D`` (required)
    2-D arrays of numbers, shapes (n, n), (n, m), (p, n), (p, m); ``m`` counts every
    input, unknown and known.
``time`` (optional, ``"discrete"`` by default)
    ``"discrete"``: the matrices are those of eq. 5.1. ``"continuous"``: they are
    ``Ẋ = A X + B U``, ``Y = C X + D U`` and are discretised with ``dt``.
``dt`` (required when continuous; recorded when discrete)
    Sample time in seconds.
``discretization`` (continuous only, ``"euler"`` by default)
    ``"euler"`` (``A = I + T A_c``, the thesis's choice in Theorems 1-4) or
    ``"zoh"`` (exact zero-order hold; beware its sampling zeros, which can make a
    relative-degree-2 plant not strongly observable, Prop. 8).
``unknown`` (optional, every input by default)
    0-based indices of the columns of ``B``/``D`` that are unknown inputs; the others
    are known inputs, which the observer reads.
``name`` (optional)
    C identifier naming the generated files (default: the file's stem).

The generated step
------------------
``<name>_step(xhat, y_window[, v_window]) -> (xhat_next, u_hat)``: called at sample
``k + L`` with ``x̂_k``, the forward output history ``(Y_k, …, Y_{k+L})`` (all outputs
of one sample together, NOTES section 2 item 1) and, if there are known inputs, their
history ``(V_k, …, V_{k+L})``; it returns ``x̂_{k+1}`` and ``Û_k``. With known inputs
``V`` (columns ``B_v``, ``D_v``, invertibility matrix ``H_v^L``) eq. 5.4 becomes

.. math::

    \\hat X_{k+1} = E \\hat X_k + F (\\mathbb{Y}_k - H_v^L \\mathbb{V}_k) + B_v V_k, \\quad
    \\hat U_k = G \\begin{pmatrix} \\hat X_{k+1} - A \\hat X_k - B_v V_k \\\\
                                    Y_k - C \\hat X_k - D_v V_k \\end{pmatrix},

whose error obeys ``e_{k+1} = E e_k`` exactly as without them (``F H_u^L = [B_u, 0]``).
A model's linearisation about a point that is not an equilibrium has a constant
term ``c = f(x_0, u_0) − x_0``: it is a known input with value 1, and the step works
in absolute coordinates (the operating point is subtracted inside).
"""
from __future__ import annotations

import hashlib
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from softgen.codegen.generate import BundleSpec, Generated, render
from softgen.core.atomic import check_dir, write_bytes
from softgen.core.errors import SoftgenError
from softgen.estimation.discretize import discretize
from softgen.estimation.uio import (ExistenceCheck, design_uio, existence_conditions,
                                    invertibility_matrix, smallest_delay)
from softgen.app.estimate import DT_RANGE
from softgen.modelfile.limits import OBSERVER_STATES
from softgen.modelfile.load import load_model
from softgen.modelfile.model import MAX_NAME, RobotModel
from softgen.symbolic.actuated import euler_steps, rk4_steps
from softgen.symbolic.actuators import McKibbenPairs, QbmoveSprings
from softgen.symbolic.rigid import FUNCTION_OPTS, RigidDynamics

__all__ = ["LinearSystem", "read_system", "linearise_model", "check_system", "ObserverCheck",
           "observer_function", "write_observer", "SystemFileError"]

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_KEYS = {"A", "B", "C", "D", "time", "dt", "discretization", "unknown", "name"}


class SystemFileError(SoftgenError, ValueError):
    """A system file is unreadable or one of its keys is wrong (names file and key)."""


@dataclass
class LinearSystem:
    """A discrete plant of eq. 5.1 with its inputs split into unknown and known ones.

    ``A``, ``B``, ``C``, ``D`` carry every input; ``unknown`` lists the unknown
    columns. ``x0``, ``y0``, ``v0`` and ``offset`` describe a linearisation (zero for
    a system given by file): the step subtracts ``y0`` and ``v0`` and adds ``x0``.
    """

    name: str
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    unknown: list[int]
    dt: float | None
    source: str
    identity: bytes
    labels: dict = field(default_factory=dict)
    x0: np.ndarray | None = None
    y0: np.ndarray | None = None
    v0: np.ndarray | None = None
    offset: np.ndarray | None = None
    note: dict = field(default_factory=dict)

    @property
    def known(self) -> list[int]:
        return [j for j in range(self.B.shape[1]) if j not in self.unknown]

    def split(self):
        """(B_u, D_u, B_v, D_v): unknown columns; known columns plus the constant term."""
        Bu, Du = self.B[:, self.unknown], self.D[:, self.unknown]
        Bv, Dv = self.B[:, self.known], self.D[:, self.known]
        if self.offset is not None:
            Bv = np.hstack([Bv, self.offset[:, None]])
            Dv = np.hstack([Dv, np.zeros((self.D.shape[0], 1))])
        return Bu, Du, Bv, Dv


# ----------------------------------------------------------------------------------- file


def _matrix(path: Path, data: dict, key: str, shape: tuple, what: str) -> np.ndarray:
    """``data[key]`` as a finite 2-D float array of ``shape`` (None = any), or one line."""
    want = f"expected a 2-D array of numbers of shape {what}"
    if key not in data:
        raise SystemFileError(f"{path}: {key}: missing required key ({want})")
    v = data[key]
    if not isinstance(v, list) or not v or not all(isinstance(r, list) for r in v):
        raise SystemFileError(f"{path}: {key}: {want} (a list of rows), got {_short(v)}")
    widths = {len(r) for r in v}
    if len(widths) != 1:
        raise SystemFileError(f"{path}: {key}: {want}; rows have different lengths "
                              f"{sorted(widths)}")
    for i, row in enumerate(v):
        for j, x in enumerate(row):
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise SystemFileError(f"{path}: {key}[{i}][{j}]: expected a finite number "
                                      f"({key} of shape {what}), got {_short(x)}")
    arr = np.array(v, dtype=float)
    if arr.shape[1] == 0:
        raise SystemFileError(f"{path}: {key}: {want}, got empty rows")
    for want_d, got in zip(shape, arr.shape):
        if want_d is not None and want_d != got:
            raise SystemFileError(f"{path}: {key}: {want}, got shape {arr.shape}")
    return arr


def _short(v) -> str:
    text = repr(v)
    return text if len(text) <= 50 else text[:47] + "..."


def read_system(path: str | Path) -> LinearSystem:
    """Read a system file (``.toml`` or ``.json``; keys in the module docstring).

    Raises
    ------
    SystemFileError
        One line naming the file and the key: missing key, wrong type, non-numeric
        or non-finite entry (with its index), shape (expected against actual), an
        unknown key, or unknown inputs whose columns of ``[B; D]`` are dependent.
    """
    path = Path(path)
    if not path.is_file():
        raise SystemFileError(f"{path}: no such file (expected a .toml or .json system file)")
    raw = path.read_bytes()
    suffix = path.suffix.lower()
    try:
        if suffix == ".toml":
            data = tomllib.loads(raw.decode("utf-8"))
        elif suffix == ".json":
            data = json.loads(raw.decode("utf-8"))
        else:
            raise SystemFileError(f"{path}: expected a .toml or .json system file, "
                                  f"got {suffix or 'no suffix'!r}")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise SystemFileError(f"{path}: not valid {suffix[1:].upper()} "
                              f"({str(exc).splitlines()[0]})") from None
    except RecursionError:           # arrays nested thousands deep (issue 36)
        raise SystemFileError(f"{path}: not valid {suffix[1:].upper()} (nested too "
                              "deeply)") from None
    if not isinstance(data, dict):
        raise SystemFileError(f"{path}: expected a table of keys A, B, C, D, got "
                              f"{type(data).__name__}")
    extra = sorted(set(data) - _KEYS)
    if extra:
        raise SystemFileError(f"{path}: {extra[0]}: unknown key (expected some of "
                              f"{', '.join(sorted(_KEYS))})")
    if isinstance(data.get("A"), list):      # the size first, before 1e6 cells are read
        OBSERVER_STATES.check(len(data["A"]), f"{path}: A")
    A = _matrix(path, data, "A", (None, None), "(n, n)")
    n = A.shape[0]
    if A.shape != (n, n):
        raise SystemFileError(f"{path}: A: expected a square 2-D array of shape (n, n), "
                              f"got shape {A.shape}")
    B = _matrix(path, data, "B", (n, None), f"(n, m) = ({n}, m) to match A")
    m = B.shape[1]
    C = _matrix(path, data, "C", (None, n), f"(p, n) = (p, {n}) to match A")
    p = C.shape[0]
    D = _matrix(path, data, "D", (p, m), f"(p, m) = ({p}, {m}) from C and B")

    time = data.get("time", "discrete")
    if time not in ("discrete", "continuous"):
        raise SystemFileError(f"{path}: time: expected \"discrete\" or \"continuous\", "
                              f"got {_short(time)}")
    dt = data.get("dt")
    if dt is not None and (isinstance(dt, bool) or not isinstance(dt, (int, float))
                           or not (math.isfinite(dt) and dt > 0)):
        raise SystemFileError(f"{path}: dt: expected a sample time > 0 in seconds, "
                              f"got {_short(dt)}")
    method = data.get("discretization", "euler")
    if "discretization" in data and time != "continuous":
        raise SystemFileError(f"{path}: discretization: only for time = \"continuous\" "
                              f"(this system is discrete)")
    if method not in ("euler", "zoh"):
        raise SystemFileError(f"{path}: discretization: expected \"euler\" or \"zoh\", "
                              f"got {_short(method)}")
    if time == "continuous":
        if dt is None:
            raise SystemFileError(f"{path}: dt: missing required key (a continuous system "
                                  f"is discretised with sample time dt)")
        A, B = discretize(A, B, float(dt), method=method)

    unknown = data.get("unknown", list(range(m)))
    if not isinstance(unknown, list) or not unknown or any(
            isinstance(j, bool) or not isinstance(j, int) or not 0 <= j < m for j in unknown) \
            or len(set(unknown)) != len(unknown):
        raise SystemFileError(f"{path}: unknown: expected distinct 0-based column indices of "
                              f"B in 0..{m - 1} (at least one), got {_short(unknown)}")
    unknown = sorted(unknown)
    BD = np.vstack([B[:, unknown], D[:, unknown]])
    r = int(np.linalg.matrix_rank(BD))
    if r < len(unknown):
        raise SystemFileError(f"{path}: B, D: the unknown-input columns {unknown} of [B; D] "
                              f"are dependent (rank {r} < {len(unknown)}): two unknown inputs "
                              f"act identically, so no observer can tell them apart")
    stem = re.sub(r"\W", "_", path.stem)
    name = data.get("name", stem if _NAME.match(stem) else f"system_{stem}")
    if not isinstance(name, str) or not _NAME.match(name) or len(name) > MAX_NAME:
        # The name becomes file and C symbol names: a 500-character one failed deep in
        # the writer (issue 36).
        what = f"{len(name)} characters" if isinstance(name, str) and _NAME.match(name) \
            else _short(name)
        raise SystemFileError(f"{path}: name: expected a C identifier of at most {MAX_NAME} "
                              f"characters, got {what}" + ("" if "name" in data else
                                                           " (from the file name; give "
                                                           "name = \"...\")"))
    return LinearSystem(name=name, A=A, B=B, C=C, D=D, unknown=unknown,
                        dt=None if dt is None else float(dt), source=str(path), identity=raw,
                        note={"time": time, **({"discretization": method}
                                              if time == "continuous" else {})})


# ------------------------------------------------------------------------ model linearisation


def _vector(text: str | None, size: int, what: str, default: np.ndarray) -> np.ndarray:
    if text is None:
        return np.asarray(default, dtype=float)
    try:
        v = np.array([float(s) for s in str(text).split(",")])
    except ValueError:
        raise SoftgenError(f"observer: {what}: expected {size} comma-separated numbers, "
                           f"got {text!r}") from None
    if v.shape != (size,) or not np.all(np.isfinite(v)):
        raise SoftgenError(f"observer: {what}: expected {size} finite comma-separated "
                           f"numbers, got {text!r}")
    return v


def linearise_model(model: RobotModel | str, *, q0: str | None = None,
                    actuator: str | None = None, dt: float = 1e-2,
                    integrator: str = "euler") -> LinearSystem:
    """A rigid model's plant step, linearised by CasADi about an operating point.

    The unknown input is an external torque ``w`` on every joint (what the invasive
    estimators of chapter 6 reconstruct); the known inputs are the plant's own
    inputs: pressures ``p`` (2n, Pa) of McKibben pairs (eq. 2.5, τ = K Φ(q) p),
    motor torques (2n) of qbmove VSAs (eq. 2.6), or joint torques of an unactuated
    chain. Outputs are the measured positions: ``q``, and ``q_a``, ``q_b`` for qbmove.
    One sample of length ``dt`` is one explicit Euler step (``integrator="euler"``,
    the thesis's discretisation in Theorems 1-2) or one RK4 step; ``A = ∂f/∂x``,
    ``B = ∂f/∂(w, u)`` at ``(x_0, u_0)`` by :func:`casadi.jacobian`, ``C`` selects the
    positions. With RK4 the exact-like sampling puts a zero near −1 into the plant,
    usually breaking Prop. 8 (the check says so).

    Operating point: ``q0`` (n values, default 0), velocities 0, and ``actuator``:
    McKibben pressures (2n, default half of each ``pressure_max``, agonist then
    antagonist per joint as in ``p``), qbmove motor positions ``(q_a, q_b)`` (2n,
    default ``q_a = q_b = q0``; motor torques 0), nothing for an unactuated chain.
    """
    if isinstance(model, str):
        model = load_model(model)
    if not isinstance(model, RobotModel):
        raise SoftgenError(f"observer: --model {model.name}: a soft body; the linearisation "
                           f"is implemented for rigid chains (McKibben, qbmove or torque-"
                           f"driven)")
    if model.floating:
        # Its q holds a quaternion and v the base twist (7 + n against 6 + n): the joint-
        # space linearisation below does not apply (issue 36: a CasADi dimension traceback).
        raise SoftgenError(f"observer: --model {model.name}: a floating base; the "
                           "linearisation is implemented for fixed-base chains and trees")
    if integrator not in ("euler", "rk4"):
        raise SoftgenError(f"observer: --integrator: expected euler or rk4, got {integrator!r}")
    lo, hi = DT_RANGE
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and lo <= dt <= hi):
        # 1e300 overflowed in the linearisation's rank tolerances (issue 36).
        raise SoftgenError(f"observer: --dt: expected a sample time between {lo:g} and "
                           f"{hi:g} s, got {dt!r}")
    n = model.dof
    dyn = RigidDynamics(model)
    m = dyn.nominal
    q0v = _vector(q0, n, "--q0", np.zeros(n))
    kind = model.actuator_type
    w = ca.SX.sym("w", n)
    if kind == "mckibben":
        act = McKibbenPairs(model)
        pmax = np.where(np.isfinite(act.pressure_max), act.pressure_max, 6e5)
        u_def = np.repeat(pmax / 2, 2)
        u0v = _vector(actuator, 2 * n, "--actuator (McKibben pressures, Pa)", u_def)
        x = ca.SX.sym("x", 2 * n)
        u = ca.SX.sym("p", 2 * n)
        q, qd = x[:n], x[n:]
        qdd = ca.substitute(dyn.forward_dynamics_expr(act.torque(m.q, u) + w),
                            ca.vertcat(m.q, m.qd), x)
        rhs_expr = ca.vertcat(qd, qdd)
        x0 = np.concatenate([q0v, np.zeros(n)])
        C = np.hstack([np.eye(n), np.zeros((n, n))])
        labels = {"states": [f"q{i+1}" for i in range(n)] + [f"qd{i+1}" for i in range(n)],
                  "known": [f"p{i+1}{s}" for i in range(n) for s in "ab"],
                  "outputs": [f"q{i+1}" for i in range(n)]}
        op = {"q0": q0v.tolist(), "pressures": u0v.tolist()}
    elif kind == "qbmove":
        springs = QbmoveSprings(model)
        mot = _vector(actuator, 2 * n, "--actuator (qbmove motor positions q_a, q_b, rad)",
                      np.concatenate([q0v, q0v]))
        u0v = np.zeros(2 * n)
        x = ca.SX.sym("x", 6 * n)
        u = ca.SX.sym("tau_motor", 2 * n)
        q, qd, qa, qad, qb, qbd = (x[i * n:(i + 1) * n] for i in range(6))
        ta = springs.spring_torque(q - qa, "a")
        tb = springs.spring_torque(q - qb, "b")
        qdd = ca.substitute(dyn.forward_dynamics_expr(-(ta + tb) + w), ca.vertcat(m.q, m.qd),
                            ca.vertcat(q, qd))
        qadd = (u[:n] + ta - springs.d_a * qad) / springs.b_a
        qbdd = (u[n:] + tb - springs.d_b * qbd) / springs.b_b
        rhs_expr = ca.vertcat(qd, qdd, qad, qadd, qbd, qbdd)
        z = np.zeros(n)
        x0 = np.concatenate([q0v, z, mot[:n], z, mot[n:], z])
        Z, I = np.zeros((n, n)), np.eye(n)
        C = np.block([[I, Z, Z, Z, Z, Z], [Z, Z, I, Z, Z, Z], [Z, Z, Z, Z, I, Z]])
        labels = {"states": [f"{g}{i+1}" for g in ("q", "qd", "qa", "qad", "qb", "qbd")
                             for i in range(n)],
                  "known": [f"tau_{s}{i+1}" for s in "ab" for i in range(n)],
                  "outputs": [f"{g}{i+1}" for g in ("q", "qa", "qb") for i in range(n)]}
        op = {"q0": q0v.tolist(), "motor_positions": mot.tolist(), "motor_torques": [0.0] * (2 * n)}
    elif not kind:
        u0v = np.zeros(n)
        x = ca.SX.sym("x", 2 * n)
        u = ca.SX.sym("tau", n)
        qdd = ca.substitute(dyn.forward_dynamics_expr(u + w), ca.vertcat(m.q, m.qd), x)
        rhs_expr = ca.vertcat(x[n:], qdd)
        x0 = np.concatenate([q0v, np.zeros(n)])
        C = np.hstack([np.eye(n), np.zeros((n, n))])
        labels = {"states": [f"q{i+1}" for i in range(n)] + [f"qd{i+1}" for i in range(n)],
                  "known": [f"tau{i+1}" for i in range(n)],
                  "outputs": [f"q{i+1}" for i in range(n)]}
        op = {"q0": q0v.tolist(), "torques": [0.0] * n}
    else:
        raise SoftgenError(f"observer: --model {model.name}: actuators of type {kind!r} are "
                           f"not linearised (McKibben, qbmove or none)")
    wu = ca.vertcat(w, u)
    rhs = ca.Function("rhs", [x, wu], [rhs_expr])
    h = float(dt)
    step = (euler_steps if integrator == "euler" else rk4_steps)(rhs, x, wu, h, 1)
    jac = ca.Function("linearised_step", [x, wu], [step, ca.jacobian(step, x), ca.jacobian(step, wu)],
                      FUNCTION_OPTS)
    wu0 = np.concatenate([np.zeros(n), u0v])
    f0, A, B = (np.array(v, dtype=float) for v in jac(x0, wu0))
    f0 = f0.ravel()
    offset = f0 - x0
    nx = x0.size
    D = np.zeros((C.shape[0], B.shape[1]))
    labels["unknown"] = [f"w{i+1}" for i in range(n)]
    labels["inputs"] = labels["unknown"] + labels["known"]
    ident = json.dumps({"model_sha256": _model_sha(model), "q0": q0v.tolist(),
                        "actuator": op, "dt": h, "integrator": integrator}).encode()
    return LinearSystem(
        name=f"{model.name}_observer", A=A, B=B, C=C, D=D, unknown=list(range(n)), dt=h,
        source=f"model {model.name}", identity=ident, labels=labels, x0=x0, y0=C @ x0,
        v0=u0v, offset=offset if np.any(offset != 0) else None,
        note={"model": model.name, "linearisation": f"one {integrator} step of length dt, "
              f"jacobian by CasADi", "operating_point": op, "n_states": nx,
              "offset_norm": float(np.linalg.norm(offset))})


def _model_sha(model: RobotModel) -> str:
    path = getattr(model, "path", None)
    if path is not None and Path(path).is_file():
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return hashlib.sha256(model.name.encode()).hexdigest()


# ---------------------------------------------------------------------------------- check


@dataclass
class ObserverCheck:
    """The conditions for one delay and the smallest delay that works (None: none ≤ n)."""

    delay: int
    conditions: list[ExistenceCheck]
    smallest: int | None

    @property
    def exists(self) -> bool:
        return all(c.holds for c in self.conditions)


def check_system(system: LinearSystem, delay: int) -> ObserverCheck:
    """Props. 7-9 (eq. 5.3) for the unknown inputs of ``system`` at ``delay``."""
    if isinstance(delay, bool) or not isinstance(delay, int) or delay < 0:
        raise SoftgenError(f"observer: --delay: expected a non-negative integer, got {delay!r}")
    n = system.A.shape[0]
    OBSERVER_STATES.check(n, f"observer: {system.source}")
    if delay > n:
        # Props. 7-9: if no delay L <= n gives an observer, none does; the block
        # matrices of a larger L only cost (100,000 ran for minutes, issue 36).
        raise SoftgenError(f"observer: --delay {delay}: at most n = {n} (the number of "
                           "states): if no delay up to n gives an observer, no larger one "
                           "does; omit --delay for the smallest that works")
    Bu, Du, _, _ = system.split()
    conds = existence_conditions(system.A, Bu, system.C, Du, delay)
    return ObserverCheck(delay, conds, smallest_delay(system.A, Bu, system.C, Du))


# ----------------------------------------------------------------------------- the C step


def observer_function(system: LinearSystem, delay: int):
    """(UIO, ``<name>_step``) for ``system`` (module docstring: the generated step)."""
    Bu, Du, Bv, Dv = system.split()
    A, C = system.A, system.C
    uio = design_uio(A, Bu, C, Du, delay=delay, dt=system.dt)
    n, p, L = A.shape[0], C.shape[0], delay
    known = system.known
    kv = len(known)
    xh = ca.SX.sym("xhat", n)
    Y = ca.SX.sym("y_window", (L + 1) * p)
    V = ca.SX.sym("v_window", (L + 1) * kv)
    x0 = np.zeros(n) if system.x0 is None else system.x0
    y0 = np.zeros(p) if system.y0 is None else system.y0
    v0 = np.zeros(kv) if system.v0 is None else system.v0
    dx = xh - ca.DM(x0)
    dY = Y - ca.DM(np.tile(y0, L + 1))
    # Known-input history, deviations from the operating point, plus the constant 1
    # of a linearisation's offset term c (a known input that never changes).
    vs = []
    for j in range(L + 1):
        vj = V[j * kv:(j + 1) * kv] - ca.DM(v0)
        vs.append(ca.vertcat(vj, 1) if system.offset is not None else vj)
    dV = ca.vertcat(*vs)
    mv = Bv.shape[1]
    if mv:
        Hv = invertibility_matrix(A, Bv, C, Dv, L)
        corr = ca.DM(Hv) @ dV
        bv, dv = ca.DM(Bv) @ vs[0], ca.DM(Dv) @ vs[0]
    else:
        corr, bv, dv = ca.DM.zeros((L + 1) * p), ca.DM.zeros(n), ca.DM.zeros(p)
    E, F, G = ca.DM(uio.E), ca.DM(uio.F), ca.DM(uio.G)
    dx_next = E @ dx + F @ (dY - corr) + bv
    u_hat = G @ ca.vertcat(dx_next - ca.DM(A) @ dx - bv, dY[:p] - ca.DM(C) @ dx - dv)
    ins, names = [xh, Y], ["xhat", "y_window"]
    if kv:
        ins.append(V)
        names.append("v_window")
    f = ca.Function(f"{system.name}_step", ins, [dx_next + ca.DM(x0), u_hat],
                    names, ["xhat_next", "u_hat"], FUNCTION_OPTS)
    return uio, f


def _mat(M) -> list:
    # json writes a float as its repr: the shortest string that reads back exactly.
    return [[float(v) for v in row] for row in np.atleast_2d(np.asarray(M, dtype=float))]


def observer_files(system: LinearSystem, delay: int, check: ObserverCheck) -> dict[str, bytes]:
    """``<name>.c``, ``<name>.h`` and ``manifest.json`` as bytes (nothing written)."""
    uio, f = observer_function(system, delay)
    Bu, Du, Bv, Dv = system.split()
    n, p = system.A.shape[0], system.C.shape[0]
    info = {
        "source": system.source,
        "equation": "thesis eq. 5.4 (delayed UIO, Prop. 9), known inputs subtracted",
        "call": (f"at sample k+{delay}: {f.name()}(xhat_k, (Y_k..Y_k+{delay})"
                 + (f", (V_k..V_k+{delay})" if system.known else "")
                 + ") -> (xhat_k+1, U_k)"),
        "delay": delay,
        "dt": system.dt,
        "dimensions": {"n": n, "m_unknown": len(system.unknown), "m_known": len(system.known),
                       "p": p},
        "unknown_inputs": list(system.unknown),
        "known_inputs": list(system.known),
        "conditions": [c.as_dict() for c in check.conditions],
        "smallest_delay": check.smallest,
        "matrices": {"A": _mat(system.A), "B": _mat(system.B), "C": _mat(system.C),
                     "D": _mat(system.D), "E": _mat(uio.E), "F": _mat(uio.F),
                     "G": _mat(uio.G)},
        **({"labels": system.labels} if system.labels else {}),
        **system.note,
    }
    if system.x0 is not None:
        info["operating_point"] = {"x0": system.x0.tolist(), "y0": system.y0.tolist(),
                                   "v0": system.v0.tolist(),
                                   "offset": None if system.offset is None
                                   else system.offset.tolist()}
    spec = BundleSpec(name=system.name,
                      functions=[Generated(f, f"delayed UIO step (eq. 5.4), delay {delay}: "
                                              f"xhat_k and the output window -> xhat_k+1, "
                                              f"U_k")],
                      identity=system.identity + f"\ndelay={delay}".encode(),
                      extra={"observer": info})
    return render(spec)


def write_observer(system: LinearSystem, delay: int, out: str | Path, *,
                   force: bool = False) -> tuple[Path, ObserverCheck]:
    """Check the conditions, and when they hold write the observer into ``out``.

    Raises
    ------
    SoftgenError
        One line: no observer for this delay (naming the failed condition and the
        smallest delay that works, if any), or an output file exists without ``force``.
    """
    chk = check_system(system, delay)
    if not chk.exists:
        raise SoftgenError(no_observer_line(system, chk))
    out = check_dir(Path(out), "observer --out")
    files = observer_files(system, delay, chk)
    taken = [out / k for k in files if (out / k).exists()]
    if taken and not force:
        raise SoftgenError(f"observer: {taken[0]} exists; add --force to overwrite it")
    out.mkdir(parents=True, exist_ok=True)
    # The manifest last: a reader that finds it finds the sources it describes.
    for fname in sorted(files, key=lambda k: k == "manifest.json"):
        write_bytes(out / fname, files[fname])
    return out, chk


def no_observer_line(system: LinearSystem, chk: ObserverCheck) -> str:
    failed = next(c for c in chk.conditions if c.holds is False)
    n = system.A.shape[0]
    tail = (f"the smallest delay with an observer is {chk.smallest} (--delay {chk.smallest})"
            if chk.smallest is not None else f"no delay L ≤ n = {n} gives one")
    return (f"observer: {system.source}: no delayed UIO with delay {chk.delay}: "
            f"{failed.line()}; {tail}")
