"""SE(3) exponential, adjoints and tangent map, finite and accurate at zero rotation.

Twists are (angular, linear) pairs as in :mod:`softgen.symbolic.recursive` and the
Cosserat conventions of docs/design.md section 4 (strain ξ = (ω; ν) = (torsion, bend_y, bend_z,
stretch, shear_y, shear_z)). With Ŵ = [ω]×, V̂ = [v]× and w = |ω|²:

Exponential
    exp(Ω) for Ω = (ω, v) is the rigid motion (R, p) with

        R = I + sinc Ŵ + cosc Ŵ²,        p = (I + cosc Ŵ + ν Ŵ²) v,

    sinc = sin θ/θ, cosc = (1 − cos θ)/θ², ν = (θ − sin θ)/θ³ (θ² = w); the series
    Σ Ŵᵏ/k! and Σ Ŵᵏ/(k+1)! folded with Ŵ³ = −w Ŵ.

Tangent map
    For g = exp(Ω(t)), the body twist is g⁻¹ġ = T(Ω) Ω̇ with the series
    T(Ω) = Σₖ (−1)ᵏ ad_Ωᵏ/(k+1)!, ad_Ω = [[Ŵ, 0], [V̂, Ŵ]]. Its diagonal blocks are the
    same series in Ŵ, T_ω = I − cosc Ŵ + ν Ŵ² (SO(3)'s right Jacobian). Its lower-left
    block is Σₖ (−1)ᵏ/(k+1)! Σ_{i+j=k−1} Ŵⁱ V̂ Ŵʲ, which is the derivative of
    (Ŵ + εV̂)ᵏ at ε = 0: the directional derivative of T_ω at ω along v,

        T_vω = −cosc V̂ + ν (ŴV̂ + V̂Ŵ) + 2 (ω·v) (−cosc′ Ŵ + ν′ Ŵ²),

    with ′ = d/dw. So T is derived from its series, not transcribed.

Numerics
    Every coefficient is a function of w = |ω|² from :mod:`softgen.symbolic.smooth`
    (Taylor branch below w = 0.1, closed form above, both finite in values and in
    derivatives of every order), so exp and T are entire functions of Ω: no 0/0 at
    zero strain (tested at 0, 1e-12, 1e-6, 1e-3 against the series).

Pure expression builders (CasADi SX).
"""
from __future__ import annotations

import casadi as ca

from softgen.symbolic.smooth import cosc_w, jet_values_from_nu, nu_w, sinc_w

__all__ = ["hat", "exp_se3", "tangent", "ad", "Ad", "Ad_inv", "coefficients"]


def hat(v) -> ca.SX:
    """[v]×, the skew matrix of a 3-vector (v × x = [v]× x)."""
    return ca.vertcat(ca.horzcat(0, -v[2], v[1]), ca.horzcat(v[2], 0, -v[0]),
                      ca.horzcat(-v[1], v[0], 0))


def ad(xi) -> ca.SX:
    """ad_ξ (6×6), ξ = (ω, v): the motion cross product ξ × η = ad_ξ η."""
    W, V = hat(xi[:3]), hat(xi[3:])
    Z = ca.SX.zeros(3, 3)
    return ca.vertcat(ca.horzcat(W, Z), ca.horzcat(V, W))


def Ad(R, p) -> ca.SX:
    """Ad_g (6×6) of g = (R, p): twists of the child frame to the parent's."""
    Z = ca.SX.zeros(3, 3)
    return ca.vertcat(ca.horzcat(R, Z), ca.horzcat(ca.mtimes(hat(p), R), R))


def Ad_inv(R, p) -> ca.SX:
    """Ad_{g⁻¹} = Ad_g⁻¹ (6×6): twists of the parent frame to the child's."""
    Z = ca.SX.zeros(3, 3)
    Rt = R.T
    return ca.vertcat(ca.horzcat(Rt, Z), ca.horzcat(-ca.mtimes(Rt, hat(p)), Rt))


def coefficients(w, *, derivatives: bool = False) -> dict:
    """sinc, cosc, ν of θ (w = θ²) and, with ``derivatives``, cosc′, ν′ (d/dw)."""
    if not derivatives:
        return {"sinc": sinc_w(w), "cosc": cosc_w(w), "nu": nu_w(w)}
    j = jet_values_from_nu(w, 1)
    return {"sinc": j[sinc_w][0], "cosc": j[cosc_w][0], "nu": j[nu_w][0],
            "dcosc": j[cosc_w][1], "dnu": j[nu_w][1]}


def exp_se3(Omega) -> tuple[ca.SX, ca.SX]:
    """(R, p) = exp(Ω) for the twist Ω = (ω, v) (module docstring)."""
    om, v = Omega[:3], Omega[3:]
    w = ca.dot(om, om)
    c = coefficients(w)
    W = hat(om)
    W2 = ca.mtimes(W, W)
    R = ca.SX.eye(3) + c["sinc"] * W + c["cosc"] * W2
    Vm = ca.SX.eye(3) + c["cosc"] * W + c["nu"] * W2
    return R, ca.mtimes(Vm, v)


def tangent(Omega) -> ca.SX:
    """T(Ω) (6×6) with g⁻¹ġ = T(Ω) Ω̇ for g = exp(Ω) (module docstring)."""
    om, v = Omega[:3], Omega[3:]
    w = ca.dot(om, om)
    c = coefficients(w, derivatives=True)
    W, V = hat(om), hat(v)
    W2 = ca.mtimes(W, W)
    Tw = ca.SX.eye(3) - c["cosc"] * W + c["nu"] * W2
    WV = ca.mtimes(W, V)
    Tvw = (-c["cosc"] * V + c["nu"] * (WV + WV.T)
           + 2 * ca.dot(om, v) * (-c["dcosc"] * W + c["dnu"] * W2))
    Z = ca.SX.zeros(3, 3)
    return ca.vertcat(ca.horzcat(Tw, Z), ca.horzcat(Tvw, Tw))


def exp_tangent_scaled(h: float, xi) -> tuple[ca.SX, ca.SX, ca.SX]:
    """(R, p, T) of exp(h ξ) and T(h ξ) for a constant h, the matrices of ξ factored out.

    The same values as :func:`exp_se3` and :func:`tangent` at Ω = h ξ, written so that
    every node of a piecewise-constant-strain segment (the same ξ, its own h) shares Ŵ,
    Ŵ², V̂ and ŴV̂ + V̂Ŵ of ξ and forms only scalar coefficients (powers of h times the
    smooth functions of w = h²|ω|²): CasADi's common-subexpression elimination then
    builds the matrices once per segment instead of once per node.
    """
    om, v = xi[:3], xi[3:]
    w = h * h * ca.dot(om, om)
    c = coefficients(w, derivatives=True)
    W, V = hat(om), hat(v)
    W2 = ca.mtimes(W, W)
    WV = ca.mtimes(W, V)
    WVs = WV + WV.T
    Wv = ca.cross(om, v)
    W2v = ca.cross(om, Wv)
    I3 = ca.SX.eye(3)
    R = I3 + (h * c["sinc"]) * W + (h * h * c["cosc"]) * W2
    p = h * v + (h * h * c["cosc"]) * Wv + (h ** 3 * c["nu"]) * W2v
    Tw = I3 - (h * c["cosc"]) * W + (h * h * c["nu"]) * W2
    ov = 2 * h * h * ca.dot(om, v)
    Tvw = (-(h * c["cosc"]) * V + (h * h * c["nu"]) * WVs
           + ov * (-(h * c["dcosc"]) * W + (h * h * c["dnu"]) * W2))
    Z = ca.SX.zeros(3, 3)
    return R, p, ca.vertcat(ca.horzcat(Tw, Z), ca.horzcat(Tvw, Tw))

