"""Emulated GioSte hardware (thesis section 10.3) and the closed loop that drives it.

The thesis ran its chapter-10 controllers on GioSte, a pneumatic arm with one or two
joints, each driven by an antagonistic McKibben pair through SMC ITV-2050 valves
(0-6 V) and read by HEDS-5500 encoders. That hardware is emulated here from what
the thesis identified on it. The controllers keep their own McKibben model of the
actuator (section 2.1), identified from the same maps (:func:`fitted_model`); what the
McKibben form cannot represent of the maps is the "residual inaccuracy of the actuator
model identification" of section 10.3.4.

Emulated hardware (every choice, and why)
-----------------------------------------
Valves (eq. 10.10)
    Steady-state pressure p = (c₂V² + c₁V + c₀)·10⁵ Pa per muscle. The controller's
    pressure command is turned into a voltage by the inverse of this map and clipped
    to [0, 6] V (:meth:`ValveMap.voltage`). Below V₀ = f⁻¹(0) ≈ 0.5-0.6 V the fit
    gives a negative gauge pressure, which a regulator fed from a compressor cannot
    make: the valve's target pressure is max(f(V), 0). The pressure in the muscle
    follows the target as a first-order lag (time constant ``valve_tau``, 0.15 s by
    default: the ITV-2050 is specified at about 0.1 s without load, and the thesis
    "adjusted the pressure response time" to stop chattering, i.e. made it no faster)
    after a transport delay (``valve_delay``, 10 ms by default: the pilot stage and
    the tubing).
Torque (eq. 10.11 and section 10.3.5)
    τ_i = A_i(q_i) u_i,a − B_i(q_i) u_i,b with the identified quadratics. The maps
    were fitted from steady states, where the muscle pressure equals the valve
    target, so here they are evaluated at the voltage *equivalent* to the actual
    (lagged) pressure, V_eq = f⁻¹(p_actual): the torque follows the air in the
    muscle, not the command. Eq. 10.11 is linear in V through V = 0, but eq. 10.10
    gives zero pressure at V₀ ≈ 0.5-0.6 V; composed literally, every muscle at zero
    pressure would pull with A(q) V₀ ≈ 3.7 N m. A McKibben muscle at zero gauge
    pressure exerts no force (F = K_g φ p, section 2.1), so the maps are read from V₀:
    u = V_eq − V₀ (:func:`map_voltage`, ``map_origin = "zero_pressure"``; the literal
    reading is ``"zero_voltage"``). Both fits agree on the slope, which is all this
    keeps of them. Joint 1 of the two-link arm uses the shoulder maps of section
    10.3.5, every other joint the one-link maps, and every muscle of joint i the valve
    maps of eq. 10.10 (section 10.3.5 says so).
Stiffness: two of them
    Eq. 10.11 also gives an identified stiffness map S_i(q, u) = S_a(q) u_a + S_b(q)
    u_b, but it is not −∂τ/∂q of the torque map: at fixed voltages
    −∂τ_i/∂q_i = −A_i'(q) V_a + B_i'(q) V_b, e.g. (2.34 + 1.42 q) V_a + (2.07 − 1.16 q)
    V_b for the one-link arm against the map's (2.34 − 0.57 q) V_a + (2.07 + 0.57 q)
    V_b. Both agree at q = 0 (the map is the linearisation there) and differ
    elsewhere. The emulated arm's *physical* stiffness is −∂τ/∂q at the actual
    pressures (:meth:`JointMaps.sigma_physical`); the controller, like the thesis's,
    "measures" σ as the identified map S at the measured angle and the voltages it
    commanded the sample before (:meth:`JointMaps.sigma_identified`): there was no
    stiffness sensor on GioSte. Metrics report both.
Links
    The controller's model values (``models/gioste_*.toml``: section 10.4 links,
    angles from the downward vertical): the thesis gives none for GioSte and fitted
    its torque maps against m g l/2 sin q with them, so the emulation's only
    mismatch is in the actuator. Viscous joint friction ``friction`` (default
    0.05 N m s/rad per joint: the bearings and the braid of the muscles) is added
    to the plant; the controller does not know it (the thesis neglects it, section
    10.3.3). Without it the lightly damped one-link mode (about 25 rad/s at
    σ = 10 N m/rad) is damped only by the feedback, which in the controller's units
    is K_d K_1, a few hundredths of a N m s/rad.
Encoders
    HEDS-5500 A12: 500 cycles per revolution, read in quadrature (×4):
    ``counts_per_rev`` = 2000, 3.1·10⁻³ rad per count. The thesis prints 1.6·10⁻³ rad
    for the same encoder, which would take 4000 counts (2π/4000 = 1.57·10⁻³); we
    follow the part number. The angle is rounded to the nearest count (the encoders
    are zeroed against the vertical, so readings are absolute).
Velocity
    A dirty derivative of the encoder reading: v_k = a v_{k−1} + (1 − a)(q_k −
    q_{k−1})/T, a = exp(−T/τ_f), τ_f = ``velocity_filter`` = 0.02 s (first-order
    low-pass at 50 rad/s on the backward difference). One count per sample would
    read 3.1 rad/s raw; the filter brings a single count's kick down to
    3.1·(1 − a) ≈ 0.15 rad/s.
Sample time
    T = 1 ms (a Simulink real-time loop on the PCIe-6323), controller held by
    zero-order hold; the controllers integrate ν and Π̂ by forward Euler over T.
    The plant (q, q̇ and the 2n muscle pressures) is integrated by RK4 with
    ``substeps`` steps per sample. Halving T is checked by the experiments.

The closed loop (:func:`loop_diagram`) is a :class:`~softgen.blocks.ClosedLoop` of
library blocks, per sample k: the reference block; the encoders
(:func:`~softgen.blocks.sensors.encoder_block`) and the dirty derivative
(:func:`~softgen.plants.hardware.dirty_derivative_block`); the identified stiffness
map of the voltages commanded at k − 1 (:meth:`GiosteEmulation.stiffness_sensor_block`);
the controller (:func:`~softgen.control.pneumatic_loop.controller_block`); the valve
interface (:meth:`GiosteEmulation.valve_block`: inverse eq. 10.10, clip); the transport
delay (:func:`~softgen.blocks.sensors.delay_block`); the arm over one sample
(:meth:`GiosteEmulation.plant_block`). The emergency stop is a stop rule
(:func:`emergency_stop`). Runs, gains and the start at rest are study code:
:mod:`softgen.studies.gioste`.

Diagnostic variant: ``GiosteEmulation(arm, hw, actuator="model")`` keeps the valves,
encoders and friction but makes the muscles the controller's own model (τ = KΦ(q)p,
σ = −KΦ_q(q)p at the valves' pressures): it separates what the hardware effects do
from what the actuator-model mismatch does.

Controller's actuator model: :func:`fitted_model` identifies each joint's pulley
radius, muscle gain and the lengths of muscle b from the torque maps by least squares
over the operating range (why: :mod:`softgen.experiments.ch10_gioste`);
:func:`kpi_vector` converts the thesis's K_π to our parameterisation.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from softgen.blocks import Block, ClosedLoop, Layout
from softgen.blocks.sensors import delay_block, encoder_block
from softgen.control.pneumatic import REFERENCE_BLOCKS, PneumaticArm
from softgen.control.pneumatic_loop import controller_block
from softgen.control.references import SmoothSteps, stiffness_reference_block
from softgen.modelfile.model import RobotModel, replace_actuator_values
from softgen.plants.hardware import dirty_derivative_block, tracking_stop
from softgen.symbolic.actuated import rk4_steps
from softgen.symbolic.rigid import FUNCTION_OPTS

BAR = 1e5          # Pa per bar: eq. 10.10 is in bar
V_MAX = 6.0        # ITV-2050 command range [0, 6] V (section 10.3.1)


# -- identified maps ---------------------------------------------------------------------

def _poly(c, x):
    """c[0] + c[1] x + c[2] x² + … (works on floats, arrays and CasADi symbols)."""
    out = 0 * x + c[-1]
    for a in reversed(c[:-1]):
        out = out * x + a
    return out


def _dpoly(c, x):
    return _poly([k * a for k, a in enumerate(c)][1:] or [0.0], x)


@dataclass(frozen=True)
class ValveMap:
    """One valve's steady state p = (c₂V² + c₁V + c₀)·10⁵ Pa (eq. 10.10)."""

    c0: float
    c1: float
    c2: float

    def pressure(self, V):
        """Pressure [Pa] the fit gives at voltage V (may be negative below V₀)."""
        return (self.c2 * V * V + self.c1 * V + self.c0) * BAR

    def voltage(self, p, sqrt=np.sqrt, fmax=np.maximum):
        """Inverse of :meth:`pressure` on its increasing branch: the voltage for ``p`` [Pa].

        Written as 2(p̃ − c₀)/(c₁ + √(c₁² + 4c₂(p̃ − c₀))), which stays accurate as
        c₂ → 0; the discriminant is clipped at 0 (it only vanishes tens of bar away).
        Pass ``sqrt=ca.sqrt, fmax=ca.fmax`` for symbols. Not clipped to [0, 6] V.
        """
        d = p / BAR - self.c0
        return 2 * d / (self.c1 + sqrt(fmax(self.c1 ** 2 + 4 * self.c2 * d, 0.0)))

    @property
    def v0(self) -> float:
        """Voltage at which the fitted pressure crosses zero."""
        return float(self.voltage(0.0))

    @property
    def p_max(self) -> float:
        """Pressure at the top of the command range, 6 V [Pa]."""
        return float(self.pressure(V_MAX))


#: Eq. 10.10, muscles a and b of the one-link arm; section 10.3.5 uses the same for
#: every joint of the two-link arm.
VALVE_A = ValveMap(-0.4543, 0.8611, 0.0025)
VALVE_B = ValveMap(-0.5382, 0.9024, -0.0036)


@dataclass(frozen=True)
class JointMaps:
    """Identified voltage→torque and voltage→stiffness maps of one joint (eq. 10.11).

    τ = A(q) V_a − B(q) V_b and S = S_a(q) V_a + S_b(q) V_b; coefficients in ascending
    powers of q.
    """

    torque_a: tuple[float, ...]
    torque_b: tuple[float, ...]
    sigma_a: tuple[float, ...]
    sigma_b: tuple[float, ...]

    def torque(self, q, Va, Vb):
        """Elastic torque [N m] of the pair (eq. 10.11, first line)."""
        return _poly(self.torque_a, q) * Va - _poly(self.torque_b, q) * Vb

    def sigma_identified(self, q, Va, Vb):
        """The identified stiffness map [N m/rad] (eq. 10.11, second line)."""
        return _poly(self.sigma_a, q) * Va + _poly(self.sigma_b, q) * Vb

    def sigma_physical(self, q, Va, Vb):
        """−∂τ/∂q at fixed voltages: the stiffness the emulated arm really has."""
        return -(_dpoly(self.torque_a, q) * Va - _dpoly(self.torque_b, q) * Vb)


#: Eq. 10.11 (one-link arm; joint 2 of the two-link arm, section 10.3.5).
ONE_LINK = JointMaps((6.96, -2.34, -0.71), (7.03, 2.07, -0.58), (2.34, -0.57), (2.07, 0.57))
#: Section 10.3.5, shoulder of the two-link arm.
SHOULDER = JointMaps((2.28, -2.87, 2.16), (2.54, 2.28, 6.09), (2.87, 0.83), (2.28, -0.83))


def joint_maps(n: int) -> tuple[JointMaps, ...]:
    """Maps of the one-link (n = 1) or two-link (n = 2) GioSte, joint by joint."""
    if n == 1:
        return (ONE_LINK,)
    if n == 2:
        return (SHOULDER, ONE_LINK)
    raise ValueError(f"GioSte has one or two joints, got {n}")


# -- the controller's actuator model ------------------------------------------------------

#: Operating range of the identification (angles in rad, gauge pressures in Pa): the
#: protocols' angles with margin, and the pressures that give GioSte's 7-19 N m/rad.
FIT_Q_RANGE = (-0.3, 0.5)
FIT_P_RANGE = (0.2 * BAR, 4.0 * BAR)


def map_voltage(V, valve: ValveMap, origin: str, fmax=np.maximum):
    """The voltage the identified maps are evaluated at, for a valve voltage ``V``.

    ``origin="zero_pressure"``: V − V₀, floored at 0, so a muscle at zero gauge pressure
    exerts no force (section 2.1: F = K_g φ p). Eq. 10.11 is linear in V through V = 0
    while eq. 10.10 gives zero pressure only at V₀ ≈ 0.5-0.6 V; composed literally
    (``origin="zero_voltage"``) the two fits give every muscle at zero pressure a pull of
    A(q) V₀ ≈ 3.7 N m, which no McKibben muscle has. Both fits agree on the slope, which
    is all that ``zero_pressure`` keeps of them.
    """
    if origin == "zero_pressure":
        return fmax(V - valve.v0, 0.0)
    if origin == "zero_voltage":
        return V
    raise ValueError(f"map_origin: expected 'zero_pressure' or 'zero_voltage', got {origin!r}")


def fit_muscles(jm: JointMaps, lengths_a: tuple[float, float], *,
                origin: str = "zero_pressure", valves: tuple[ValveMap, ValveMap] | None = None,
                q_range=FIT_Q_RANGE, p_range=FIT_P_RANGE) -> dict:
    """A McKibben pair (section 2.1) identified from the maps of one joint.

    The controller's model gives muscle a the torque K φ_a(q) p_a with
    φ_a = (l_n,a − qR)² − l_m,a², φ_b = (l_n,b + qR)² − l_m,b², K = K_g R; the emulated
    muscle gives A(q) u_a(p_a) with u the map voltage of the pressure (eq. 10.10
    inverted, :func:`map_voltage`). Least squares over a grid of ``q_range`` ×
    ``p_range`` fits K, R and the lengths of muscle b (the thesis identified "the nominal
    and minimum lengths of the two muscles", section 10.3.3), so unequal muscles are
    modelled, not left as a torque bias at co-contraction. Muscle a keeps
    ``lengths_a`` = (l_n, l_min) of the model file: K φ is invariant under
    (K, R, l) → (cK, R/√c, l/√c), and with every length free the fit runs to the
    unphysical corner l_min → l_n, K → ∞ (a flatter profile than any muscle near its
    rest length gives). What no McKibben pair represents stays a mismatch: the maps'
    q² terms have the opposite sign of K R².

    Returns ``{"radius", "gain", "nominal_length": (a, b), "min_length": (a, b),
    "rms_error"}``, the last the fit's rms torque error in N m over the grid.
    """
    # scipy here, not at the top: only the fitted controller models pay its import time.
    from scipy.optimize import least_squares

    q, p = np.meshgrid(np.linspace(*q_range, 41), np.linspace(*p_range, 21))
    q, p = q.ravel(), p.ravel()
    va, vb = valves or (VALVE_A, VALVE_B)
    ua = map_voltage(va.voltage(p), va, origin)
    ub = map_voltage(vb.voltage(p), vb, origin)
    y = np.concatenate([_poly(jm.torque_a, q) * ua, _poly(jm.torque_b, q) * ub])
    lna, lma = (float(v) for v in lengths_a)

    def model(x):
        K, R, lnb, lmb = x
        return np.concatenate([K * ((lna - q * R) ** 2 - lma ** 2) * p,
                               K * ((lnb + q * R) ** 2 - lmb ** 2) * p])

    # Start: muscle a's level and slope at q = 0 matched, muscle b equal to it.
    c0 = _poly(jm.torque_a, 0.0) / (va.c1 * BAR)
    c1 = -_dpoly(jm.torque_a, 0.0) / (va.c1 * BAR)
    K0 = c0 / (lna ** 2 - lma ** 2)
    x0 = np.array([K0, c1 / (2 * K0 * lna), lna, lma])
    sol = least_squares(lambda x: model(x * x0) - y, np.ones(4), method="trf",
                        bounds=(1e-3, np.inf), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    K, R, lnb, lmb = sol.x * x0
    if not (sol.success and lmb < lnb):
        raise ValueError(f"fit_muscles: no physical McKibben pair fits these maps "
                         f"(l_n,b = {lnb:.4g}, l_m,b = {lmb:.4g} m)")
    return {"radius": float(R), "gain": float(K / R), "nominal_length": (lna, float(lnb)),
            "min_length": (lma, float(lmb)),
            "rms_error": float(np.sqrt(np.mean((model(sol.x * x0) - y) ** 2)))}


def fitted_model(model: RobotModel, *, origin: str = "zero_pressure") -> RobotModel:
    """``model`` with each joint's McKibben pair identified from the maps (:func:`fit_muscles`).

    Named ``<name>_fitted`` so that its generated functions never collide with the
    original's. Muscle a keeps its lengths from the model file.
    """
    acts = []
    for a, jm in zip(model.actuators, joint_maps(model.dof)):
        fit = fit_muscles(jm, (a["nominal_length"][0], a["min_length"][0]), origin=origin)
        acts.append(replace_actuator_values(
            model, a, radius=fit["radius"], gain=fit["gain"],
            nominal_length=fit["nominal_length"], min_length=fit["min_length"]))
    return dataclasses.replace(model, name=f"{model.name}_fitted", actuators=tuple(acts))


def gravity_columns(arm: PneumaticArm) -> np.ndarray:
    """Mask of the base parameters that only multiply gravity terms (g sin q, …)."""
    n = arm.n
    q, z = np.full(n, 0.3), np.zeros(n)
    grav = arm.dyn.regressor(q, z, z, z)
    inertial = arm.dyn.regressor(q, np.ones(n), np.ones(n), np.ones(n)) - grav
    return np.all(np.abs(inertial) < 1e-12, axis=0) & np.any(np.abs(grav) > 0, axis=0)


def kpi_vector(arm: PneumaticArm, kpi: float, *, per_g2: bool = True) -> np.ndarray:
    """K_π per base parameter, in the thesis's parameterisation.

    The thesis's regressors carry sin q, not g sin q (section 10.3.3: Y_* = (q̈_r,
    sin q); eq. 10.9 likewise), so its gravity parameters are g times ours; a
    diagonal gain K_π on them is K_π/g² on ours (Π̇ = K_π Yᵀ s).
    """
    g = float(arm.model.nominal.get("g", 9.81))
    out = np.full(arm.n_params, float(kpi))
    if per_g2:
        out[gravity_columns(arm)] /= g * g
    return out


# -- the emulation -----------------------------------------------------------------------

@dataclass(frozen=True)
class HardwareConfig:
    """Emulation choices (module docstring); defaults are the experiments' values."""

    valve_tau: float = 0.15          # s, first-order pressure response
    valve_delay: float = 0.01        # s, transport delay before the lag
    friction: float = 0.05           # N m s/rad, viscous, every joint
    counts_per_rev: int = 2000       # HEDS-5500 A12: 500 cycles/rev, quadrature (x4) decoding
    velocity_filter: float = 0.02    # s, dirty-derivative time constant
    substeps: int = 2                # RK4 steps of the plant per sample
    map_origin: str = "zero_pressure"  # how eq. 10.10 and 10.11 compose (map_voltage)

    @classmethod
    def from_dict(cls, d: dict | None) -> HardwareConfig:
        return cls(**(d or {}))


class GiosteEmulation:
    """Symbolic emulated GioSte for a controller ``arm`` (its links, the identified maps).

    Muscle order everywhere is the controller's: (p_1a, p_1b, …, p_na, p_nb).
    """

    def __init__(self, arm: PneumaticArm, hw: HardwareConfig = HardwareConfig(), *,
                 actuator: str = "identified"):
        if actuator not in ("identified", "model"):
            raise ValueError(f"actuator: expected 'identified' or 'model', got {actuator!r}")
        self.arm = arm
        self.hw = hw
        self.n = arm.n
        self.name = arm.name
        self.actuator = actuator
        # Function names <model>_<tag>_<quantity>: both variants can share a bundle dir.
        self.tag = "gioste" if actuator == "identified" else "matched"
        self.diagrams: dict = {}            # (kind, dt) -> loop_diagram, built once
        self.joints = joint_maps(self.n)
        self.valves = (VALVE_A, VALVE_B)

    def fname(self, quantity: str) -> str:
        return f"{self.name}_{self.tag}_{quantity}"

    @property
    def state_layout(self) -> Layout:
        """The arm's state (q, q̇, p): angles, velocities, the 2n muscle pressures."""
        return Layout([("q", self.n, "rad"), ("qd", self.n, "rad/s"), ("p", 2 * self.n, "Pa")])

    # numeric helpers ------------------------------------------------------------------
    @property
    def encoder_step(self) -> float:
        return 2 * math.pi / self.hw.counts_per_rev

    @property
    def p_max(self) -> np.ndarray:
        """Per joint, the smaller of its two muscles' pressures at 6 V [Pa]."""
        return np.full(self.n, min(v.p_max for v in self.valves))

    def voltages(self, p):
        """Unclipped voltages for pressures ``p`` (…, 2n), by the inverse of eq. 10.10."""
        p = np.asarray(p, dtype=float)
        V = np.empty_like(p)
        V[..., 0::2] = VALVE_A.voltage(p[..., 0::2])
        V[..., 1::2] = VALVE_B.voltage(p[..., 1::2])
        return V

    def pressures(self, V):
        V = np.asarray(V, dtype=float)
        p = np.empty_like(V)
        p[..., 0::2] = VALVE_A.pressure(V[..., 0::2])
        p[..., 1::2] = VALVE_B.pressure(V[..., 1::2])
        return p

    def calibrated_gain(self, sigma_range) -> np.ndarray:
        """K̂ per joint: the controller's K that best matches the identified map.

        At q = 0 and zero torque both muscles of a joint get the same pressure p in
        the controller's model (φ_a = φ_b there), whose stiffness is K·x with
        x = −Φ_q p. For σ on a grid over ``sigma_range`` we solve S(0, V(p), V(p)) = σ
        for p (S rises with p) and fit σ = K̂ x through the origin (least squares).
        This is what an identification gives the open-loop stiffness law of Tonietti
        and Bicchi (and Theorem 5's σ̇_d feed-forward): one gain, exact only at q = 0
        and as far as the valve map is linear (its c₂ term; with ``map_origin =
        "zero_voltage"`` also its offset V₀).
        """
        if self.actuator == "model":
            return np.array(self.arm.act.K, dtype=float)
        lo, hi = float(min(sigma_range)), float(max(sigma_range))
        grid = np.linspace(lo, hi, 9) if hi > lo else np.array([lo])
        qs = ca.SX.sym("q", self.n)
        Phi_q0 = np.array(ca.Function("Phi_q", [qs], [ca.densify(self.arm.act.Phi_q(qs))])(
            np.zeros(self.n)))
        K = np.empty(self.n)
        for i, jm in enumerate(self.joints):
            xs = []
            for s in grid:
                a, b = 0.0, 8e5
                for _ in range(80):     # bisection: S is increasing in p
                    m = 0.5 * (a + b)
                    S = jm.sigma_identified(
                        0.0, map_voltage(VALVE_A.voltage(m), VALVE_A, self.hw.map_origin),
                        map_voltage(VALVE_B.voltage(m), VALVE_B, self.hw.map_origin))
                    a, b = (m, b) if S < s else (a, m)
                p = 0.5 * (a + b)
                xs.append(-(Phi_q0[i, 2 * i] + Phi_q0[i, 2 * i + 1]) * p)
            xs = np.array(xs)
            K[i] = float(grid @ xs / (xs @ xs))
        return K

    # symbolic pieces ------------------------------------------------------------------
    def _veq(self, p):
        """Voltages for pressures ``p`` by the inverse of eq. 10.10 (symbolic, 2n, unclipped)."""
        out = []
        for j in range(2 * self.n):
            v = self.valves[j % 2]
            out.append(v.voltage(p[j], sqrt=ca.sqrt, fmax=ca.fmax))
        return ca.vertcat(*out)

    def _maps(self, q, V):
        """(τ, σ_physical, σ_identified) of every joint at angles q and voltages V.

        With ``actuator="model"`` (a diagnostic, not GioSte) the muscles are the
        controller's own model at the valves' steady pressures: τ = KΦ(q)p and both
        stiffnesses −KΦ_q(q)p, so only valves, sensors and friction differ from it.
        """
        if self.actuator == "model":
            p = ca.vertcat(*[ca.fmax(self.valves[j % 2].pressure(V[j]), 0.0)
                             for j in range(2 * self.n)])
            qs = ca.SX.sym("qs", self.n)     # Φ_q is built by differentiation: needs a symbol
            tau, sig = ca.substitute([self.arm.act.torque(qs, p), self.arm.act.stiffness(qs, p)],
                                     [qs], [q])
            return tau, sig, sig
        tau, sp, si = [], [], []
        origin = self.hw.map_origin
        for i, jm in enumerate(self.joints):
            Va = map_voltage(V[2 * i], VALVE_A, origin, fmax=ca.fmax)
            Vb = map_voltage(V[2 * i + 1], VALVE_B, origin, fmax=ca.fmax)
            tau.append(jm.torque(q[i], Va, Vb))
            sp.append(jm.sigma_physical(q[i], Va, Vb))
            si.append(jm.sigma_identified(q[i], Va, Vb))
        return ca.vertcat(*tau), ca.vertcat(*sp), ca.vertcat(*si)

    def plant_fun(self) -> ca.Function:
        """``<model>_gioste_plant``: one sample of the emulated arm, valve targets held.

        x = (q, q̇, p) with p the 2n actual muscle pressures; B q̈ + C q̇ + G + β q̇ =
        τ(q, V_eq(p)) (eq. 10.11 at the voltage equivalent of the actual pressures),
        ṗ = (p_target − p)/τ_v; ``substeps`` RK4 steps over h.
        """
        n, dyn, lay = self.n, self.arm.dyn, self.state_layout
        xs, us = ca.SX.sym("xs", lay.size), ca.SX.sym("us", 2 * n)
        q, qd, p = (lay.split(xs)[k] for k in ("q", "qd", "p"))
        tau, _, _ = self._maps(q, self._veq(p))
        m = dyn.nominal
        qdd = ca.substitute(dyn.forward_dynamics_expr(tau - self.hw.friction * qd),
                            ca.vertcat(m.q, m.qd), ca.vertcat(q, qd))
        rhs = ca.Function("rhs", [xs, us], [ca.vertcat(qd, qdd, (us - p) / self.hw.valve_tau)])
        x, u, h = ca.SX.sym("x", lay.size), ca.SX.sym("p_target", 2 * n), ca.SX.sym("h")
        z = rk4_steps(rhs, x, u, h, self.hw.substeps)
        return ca.Function(self.fname("plant"), [x, u, h], [z],
                           ["x", "p_target", "h"], ["x_next"], FUNCTION_OPTS)

    def interface_fun(self) -> ca.Function:
        """``<model>_gioste_valves``: commanded pressures → (V clipped, valve targets, V raw)."""
        p = ca.SX.sym("p_cmd", 2 * self.n)
        raw = self._veq(p)
        V = ca.fmin(ca.fmax(raw, 0.0), V_MAX)
        tgt = ca.vertcat(*[ca.fmax(self.valves[j % 2].pressure(V[j]), 0.0)
                           for j in range(2 * self.n)])
        return ca.Function(self.fname("valves"), [p], [V, tgt, raw], ["p_cmd"],
                           ["V", "p_target", "V_raw"], FUNCTION_OPTS)

    def truth_fun(self) -> ca.Function:
        """``<model>_gioste_truth``: (q, p actual) → (τ, σ physical, σ map at V_eq)."""
        q, p = ca.SX.sym("q", self.n), ca.SX.sym("p", 2 * self.n)
        tau, sp, si = self._maps(q, self._veq(p))
        return ca.Function(self.fname("truth"), [q, p], [tau, sp, si], ["q", "p"],
                           ["tau", "sigma_physical", "sigma_identified"], FUNCTION_OPTS)

    def maps_fun(self) -> ca.Function:
        """``<model>_gioste_maps``: (q, V) → (τ, σ physical, σ identified), for tests."""
        q, V = ca.SX.sym("q", self.n), ca.SX.sym("V", 2 * self.n)
        return ca.Function(self.fname("maps"), [q, V], list(self._maps(q, V)),
                           ["q", "V"], ["tau", "sigma_physical", "sigma_identified"],
                           FUNCTION_OPTS)


    # blocks -----------------------------------------------------------------------------
    def valve_block(self, *, name: str = "valves") -> Block:
        """Valve interface (eq. 10.10 inverted): commanded pressures ``p_cmd`` → voltages.

        Emits ``V`` (clipped to [0, 6] V, what the valves get), ``V_raw`` (before
        clipping) and ``p_target`` = max(f(V), 0), the pressure each valve settles to (no
        vacuum below V₀). Static: it takes the diagram's sample time.
        """
        f, m = self.interface_fun(), 2 * self.n

        def body(x, u, p):
            V, tgt, raw = f(u["p_cmd"])
            return {}, {"V": V, "p_target": tgt, "V_raw": raw}

        return Block.define(name, dt=None, inputs=[("p_cmd", m, "Pa")],
                            outputs=[("V", m, "V"), ("p_target", m, "Pa"), ("V_raw", m, "V")],
                            body=body, doc="GioSte valve interface, inverse eq. 10.10, clipped")

    def plant_block(self, dt: float, *, name: str = "plant") -> Block:
        """The emulated arm over one sample (:meth:`plant_fun`), valve targets held.

        State (q, q̇, p) with p the 2n actual muscle pressures; outputs them at the sample
        and the truth there: torque ``tau``, ``sigma_physical`` (−∂τ/∂q) and
        ``sigma_identified`` (the eq. 10.11 map) at the voltages equivalent to p.
        """
        n, f, truth, lay = self.n, self.plant_fun(), self.truth_fun(), self.state_layout

        def body(x, u, p):
            xn = f(lay.join(x), u["p_target"], dt)
            tau, sp, si = truth(x["q"], x["p"])
            return (lay.split(xn), {**x, "tau": tau, "sigma_physical": sp,
                                    "sigma_identified": si})

        return Block.define(name, dt=dt, state=lay, inputs=[("p_target", 2 * n, "Pa")],
                            outputs=list(lay) + [("tau", n, "N m"), ("sigma_physical", n, "N m/rad"),
                                          ("sigma_identified", n, "N m/rad")],
                            body=body, doc=f"emulated GioSte ({self.actuator} muscles)",
                            meta={"model": self.name})

    def stiffness_sensor_block(self, dt: float, *, name: str = "stiff") -> Block:
        """The stiffness the thesis's controller "measured": σ_m = S(q_m, V_{k−1}).

        There was no stiffness sensor on GioSte: σ is the identified map (eq. 10.11) at the
        encoder reading ``q_m`` and the voltages ``V`` commanded the sample before (state
        ``V_prev``).
        """
        n = self.n
        maps = self.maps_fun()

        def body(x, u, p):
            return {"V_prev": u["V"]}, {"sigma": maps(u["q_m"], x["V_prev"])[2]}

        return Block.define(name, dt=dt, state=[("V_prev", 2 * n, "V")],
                            inputs=[("q_m", n, "rad"), ("V", 2 * n, "V")],
                            outputs=[("sigma", n, "N m/rad")], body=body,
                            doc="identified stiffness map of the last voltages (eq. 10.11)")

    def sensor_blocks(self, dt: float) -> list[Block]:
        """HEDS-5500 encoders (``enc``: the angle rounded to the count,
        :func:`~softgen.blocks.sensors.encoder_block`) and the dirty-derivative velocity
        (``vel``, :func:`~softgen.plants.hardware.dirty_derivative_block`)."""
        return [encoder_block("enc", {"q": self.n}, self.hw.counts_per_rev),
                dirty_derivative_block(self.n, dt, velocity_filter=self.hw.velocity_filter)]

    # static solves on prebuilt functions -----------------------------------------------
    def residual_fun(self) -> ca.Function:
        """``(q, p) -> (r, dr/dq)``: τ(q, V_eq(p)) − G(q), the net torque at rest, and its
        Jacobian."""
        if not hasattr(self, "_residual"):
            q, p = ca.SX.sym("q", self.n), ca.SX.sym("p", 2 * self.n)
            r = self.truth_fun()(q, p)[0] - self.arm.dyn.gravity_fun()(q)
            object.__setattr__(self, "_residual", ca.Function(
                "gioste_rest_residual", [q, p], [r, ca.jacobian(r, q)], ["q", "p"],
                ["r", "J"]))
        return self._residual


def delay_samples(hw: HardwareConfig, dt: float) -> int:
    """The valves' transport delay in whole samples of ``dt``."""
    return int(round(hw.valve_delay / dt))


def reference_array(channels_q: list[SmoothSteps], channels_sigma: list[SmoothSteps],
                    t) -> np.ndarray:
    """(K, 6n) reference rows: q_d, q̇_d, q̈_d, q⃛_d, σ_d, σ̇_d per joint at times ``t``."""
    Q = np.stack([c(t) for c in channels_q], axis=1)       # (4, n, K)
    S = np.stack([c(t) for c in channels_sigma], axis=1)
    return np.concatenate([Q[0], Q[1], Q[2], Q[3], S[0], S[1]], axis=0).T


def reference_layout(n: int) -> Layout:
    """The controllers' reference vector (:data:`~softgen.control.pneumatic.REFERENCE_BLOCKS`:
    q_d, q̇_d, q̈_d, q⃛_d, σ_d, σ̇_d, n entries each)."""
    return Layout([(b, n) for b in REFERENCE_BLOCKS])


def step_reference(q: list, sigma: list, duration: float, dt: float) -> np.ndarray:
    """(K × 6n) reference over [0, ``duration``] (K = duration/dt + 1 samples) from one
    :class:`SmoothSteps` or constant per joint for the angles ``q`` and stiffnesses
    ``sigma``."""
    steps = lambda x: (x if isinstance(x, SmoothSteps)  # noqa: E731
                       else SmoothSteps((0.0,), (float(x),), 1.0)).check()
    return reference_array([steps(x) for x in q], [steps(x) for x in sigma],
                           np.arange(int(round(duration / dt)) + 1) * dt)


def reference_input_block(n: int, *, name: str = "ref") -> Block:
    """Passes an external reference ``u`` (6n: q_d, q̇_d, q̈_d, q⃛_d, σ_d, σ̇_d) on as
    ``ref`` and emits ``q_d`` and ``sigma_d`` alone (for stops, metrics, figures)."""
    return Block.define(name, dt=None, inputs=[("u", 6 * n)],
                        outputs=[("ref", 6 * n), ("q_d", n, "rad"), ("sigma_d", n, "N m/rad")],
                        body=lambda x, u, p: ({}, {"ref": u["u"], **{
                            k: reference_layout(n).split(u["u"])[k] for k in ("q_d", "sigma_d")}}),
                        doc="external reference of the chapter-10 controllers")


def loop_diagram(emu: GiosteEmulation, kind: str, dt: float, *,
                 reference: list | None = None) -> ClosedLoop:
    """Controller ``kind`` on the emulated GioSte, one sample per ``dt``.

    ref → encoders + dirty derivative → σ map of the last voltages → controller → valve
    interface → delay line → arm. ``reference``: (q channels, σ channels) of
    :class:`SmoothSteps` for a reference block; without it the reference is the
    external input ``ref`` (6n per sample, :func:`reference_array`), so one compiled
    loop serves every schedule.
    """
    n = emu.n
    ref = (stiffness_reference_block("ref", *reference) if reference is not None
           else reference_input_block(n))
    d = delay_samples(emu.hw, dt)
    blocks = [ref, *emu.sensor_blocks(dt), emu.stiffness_sensor_block(dt),
              controller_block(emu.arm, kind, dt), emu.valve_block(), emu.plant_block(dt)]
    wires = [("enc.q_m", "ctrl.q"), ("vel.v", "ctrl.qd"), ("ref.ref", "ctrl.ref"),
             ("ctrl.p", "valves.p_cmd")]
    if d:       # the valves' transport delay (state delay.p_target_line, oldest first)
        blocks.append(delay_block("delay", {"p_target": 2 * n}, d, dt=dt))
        wires += [("valves.p_target", "delay.p_target"), ("delay.p_target_d", "plant.p_target")]
    else:
        wires.append(("valves.p_target", "plant.p_target"))
    if reference is None:
        wires.append(("ext.ref", "ref.u"))
    tag = f"{emu.name}_{emu.tag}_{kind}_dt{dt:.3e}".replace(".", "p").replace("-", "m")
    return ClosedLoop(tag.replace("+", ""), blocks, wires,
                      externals={"ref": 6 * n} if reference is None else None)


def emergency_stop(bound: float):
    """GioSte's emergency stop as a ``stop=`` condition: |q − q_d| > ``bound`` on a joint,
    or the arm's state or the controller's command not finite."""
    return tracking_stop(bound, "plant.q", "ref.q_d",
                         finite=("plant.q", "plant.qd", "plant.p", "ctrl.p"))


#: What :func:`emergency_stop` reads: record at least these.
STOP_SIGNALS = ("plant.q", "plant.qd", "plant.p", "ref.q_d", "ctrl.p")


def equilibrium(emu: GiosteEmulation, p: np.ndarray, q0: np.ndarray, *,
                tol: float = 1e-12, max_iter: int = 30) -> np.ndarray:
    """Angle where the emulated arm rests under constant muscle pressures ``p``.

    Newton on τ(q, V_eq(p)) − G(q) = 0 from ``q0``, residual and Jacobian from one
    prebuilt function (:meth:`GiosteEmulation.residual_fun`).
    """
    f = emu.residual_fun()
    q = np.array(q0, dtype=float)
    for _ in range(max_iter):
        r, J = (np.array(v) for v in f(q, p))
        dq = np.linalg.solve(J, -r.ravel())
        q = q + dq
        if np.max(np.abs(dq)) < tol:
            break
    return q
