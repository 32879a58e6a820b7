"""Joint friction as regressor columns: viscous and Coulomb, linear in their coefficients.

The friction torque of joint i is taken as

    τ_f,i = f_v,i q̇_i + f_c,i sign(q̇_i)

(the standard model of rigid-body identification, e.g. Gautier & Khalil 1990; the
thesis's plants carry the viscous part as D q̇, eq. 2.6). It is linear in the
coefficients, so it adds 2n columns to the base regressor: Y_f(q̇) = [diag(q̇),
diag(sign(q̇))] with τ_f = Y_f (f_v; f_c). ``smoothing`` > 0 replaces sign(x) by
tanh(x/ε), differentiable at rest, for plants that are integrated.
"""
from __future__ import annotations

import casadi as ca


def friction_columns(qd: ca.SX, *, viscous: tuple[bool, ...] | bool = True,
                     coulomb: tuple[bool, ...] | bool = True,
                     smoothing: float = 0.0) -> tuple[ca.SX, list[str]]:
    """Columns of the friction regressor and their names.

    Parameters
    ----------
    qd
        n×1 joint velocities.
    viscous, coulomb
        Whether each joint gets a viscous (``fv<i>``) / Coulomb (``fc<i>``) column; a
        bool applies to every joint. A joint whose damping is already an uncertain
        parameter of the model has its viscous column in the base regressor.
    smoothing
        ε of tanh(q̇/ε) in place of sign(q̇); 0 for the plain sign.

    Returns
    -------
    (Y_f, names)
        n×m SX (m the number of columns asked for) and the coefficient names.
    """
    n = qd.shape[0]
    vis = (viscous,) * n if isinstance(viscous, bool) else tuple(viscous)
    cou = (coulomb,) * n if isinstance(coulomb, bool) else tuple(coulomb)
    if len(vis) != n or len(cou) != n:
        raise ValueError(f"friction_columns: expected {n} flags per kind, got "
                         f"{len(vis)} viscous and {len(cou)} Coulomb")
    if smoothing < 0:
        raise ValueError(f"smoothing: expected a non-negative number, got {smoothing!r}")
    cols, names = [], []
    for kind, flags in (("fv", vis), ("fc", cou)):
        for i in range(n):
            if not flags[i]:
                continue
            col = ca.SX.zeros(n, 1)
            if kind == "fv":
                col[i] = qd[i]
            else:
                col[i] = ca.tanh(qd[i] / smoothing) if smoothing > 0 else ca.sign(qd[i])
            cols.append(col)
            names.append(f"{kind}{i + 1}")
    return (ca.horzcat(*cols) if cols else ca.SX.zeros(n, 0)), names

