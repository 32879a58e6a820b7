"""How the symbolic routes scale on planar chains of n identical links.

The explicit route forms B and C (``n²`` entries, each a sum over the chain), so
its expression grows roughly quadratically in n; the matrix-free route only takes
directional derivatives of the kinetic energy and grows linearly; the recursive
(Newton–Euler) route grows linearly with a constant about three times smaller
(about 91 instructions per planar joint against 273). The same holds
for the adaptive law's regressor products: forming Y is quadratic, Y δ and Yᵀ s
without Y are linear (:data:`ROUTES`). This module measures them on the same chains: instructions of the CasADi function, bytes of
generated C, time to build, generate and compile, and nanoseconds per call timed
in C (:func:`softgen.codegen.cbench.time_in_c`, linked to the library compiled
for the compile time, so each route is compiled once).

Example
-------
>>> rows = scaling_table((2, 5, 10), calls=20000)   # doctest: +SKIP
>>> print(format_table(rows))                       # doctest: +SKIP
"""
from __future__ import annotations

import dataclasses
import tempfile
import time
from pathlib import Path
from typing import Any

import casadi as ca

from softgen.codegen.build import compile_shared
from softgen.codegen.cbench import time_in_c
from softgen.core.errors import BuildError
from softgen.modelfile.model import RobotModel
from softgen.modelfile.load import load_model
from softgen.symbolic.linear import LinearParameters
from softgen.symbolic.mechanics import Mechanics

__all__ = ["chain_model", "spatial_chain_model", "measure_route", "scaling_table",
           "format_table"]

#: Address-space cap for one compiler run. gcc -O3 on one huge straight-line
#: function can take many GiB; the cap turns that into a BuildError, not an OOM kill.
COMPILE_MEMORY_BYTES = 4 * 2**30
#: Wall-clock cap for one compiler run, in seconds.
COMPILE_TIMEOUT = 600.0

_LINK = """
[[links]]
name = "link{i}"
joint = "revolute"
mass = 0.1
length = 0.1
com = 0.05
inertia = 1e-4
"""


def chain_model(n: int) -> RobotModel:
    """A planar chain of ``n`` identical revolute links.

    Each link has m = 0.1 kg, l = 0.1 m, centre of mass mid-link and
    I = 1e-4 kg m² about it. The model is written to a temporary TOML file and
    loaded with :func:`softgen.modelfile.load.load_model`, so it passes the same checks
    as a shipped model; the file is removed afterwards and ``path`` is None.

    Raises
    ------
    ValueError
        ``n`` is not a positive integer.
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n: expected a positive integer, got {n!r}")
    text = (f'[model]\nname = "planar_chain{n}"\nkind = "planar"\n'
            f'description = "Planar chain of {n} identical revolute links"\n'
            'source = "softgen.app.chains"\n\n[gravity]\ng = 9.81\n'
            + "".join(_LINK.format(i=i) for i in range(1, n + 1)))
    with tempfile.TemporaryDirectory(prefix="softgen-chain-") as tmp:
        path = Path(tmp) / f"planar_chain{n}.toml"
        path.write_text(text)
        model = load_model(path)
    # The file is gone: a path pointing at it would make source_text() fail later.
    return dataclasses.replace(model, path=None)


_SPATIAL_LINK = """
[[links]]
name = "link{i}"
joint = "{joint}"
axis = {axis}
origin_xyz = [0.02, 0.0, 0.1]
mass = 0.5
com = [0.01, 0.005, 0.05]
inertia = [2e-3, 2.2e-3, 1e-3, 1e-5, -2e-5, 3e-5]
"""


def spatial_chain_model(n: int) -> RobotModel:
    """A spatial chain of ``n`` links: revolute joints alternately about z and y, every
    fifth joint prismatic along x.

    Each link sits 0.1 m up and 0.02 m sideways from its parent's origin and has
    m = 0.5 kg, an off-axis centre of mass and a full (off-diagonal) inertia, so
    every inertial parameter acts; with no ``[parameters]`` table all of them
    (masses, centres of mass, inertias) are uncertain. Consecutive z and y axes
    are perpendicular and each y axis is parallel to the next-but-one: the
    structural regroupings of a generic arm, with no planar degeneracy. Loaded
    like :func:`chain_model` (same checks, ``path`` None).

    Raises
    ------
    ValueError
        ``n`` is not a positive integer.
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n: expected a positive integer, got {n!r}")

    def link(i: int) -> str:
        if i % 5 == 0:
            return _SPATIAL_LINK.format(i=i, joint="prismatic", axis="[1.0, 0.0, 0.0]")
        axis = "[0.0, 0.0, 1.0]" if i % 2 else "[0.0, 1.0, 0.0]"
        return _SPATIAL_LINK.format(i=i, joint="revolute", axis=axis)
    text = (f'[model]\nname = "spatial_chain{n}"\nkind = "spatial"\n'
            f'description = "Spatial chain of {n} links"\n'
            'source = "softgen.app.chains"\n\n[gravity]\nvector = [0.0, 0.0, -9.81]\n'
            + "".join(link(i) for i in range(1, n + 1)))
    with tempfile.TemporaryDirectory(prefix="softgen-chain-") as tmp:
        path = Path(tmp) / f"spatial_chain{n}.toml"
        path.write_text(text)
        model = load_model(path)
    return dataclasses.replace(model, path=None)


#: What each route measures. The first three build τ = B q̈_r + C q̇_r + G; the
#: base-* ones are the bundle's products with the base regressor (numeric base
#: parameters, recursive products where smaller); the last three are the adaptive
#: law's products with the regressor of the linear-in-inertial-parameters form of
#: the energy route (softgen.symbolic.linear).
ROUTES = {
    "explicit": "tau, forming B and C = 1/2 (Bdot + J - J^T)",
    "matrix-free": "tau, C qd_r by jtimes/gradient of the kinetic energy",
    "recursive": "tau, Newton-Euler recursion with the Christoffel C (symbolic/recursive.py)",
    "base-y-pi": "Y pi over the base parameters, as RigidDynamics(route='auto') builds it",
    "base-yt-s": "Y^T s over the base parameters, as RigidDynamics(route='auto') builds it",
    "y-delta": "Y delta without forming Y (tau linear in delta)",
    "yt-s": "Y^T s without forming Y (gradient of s^T tau)",
    "y-formed": "Y itself (jacobian of tau in delta)",
}
#: Routes whose expression grows about quadratically in n.
QUADRATIC = ("explicit", "y-formed")


def _route_function(model: RobotModel, route: str, name: str) -> ca.Function:
    if route in ("base-y-pi", "base-yt-s"):
        from softgen.symbolic.rigid import RigidDynamics
        dyn = RigidDynamics(model)
        f = (dyn.regressor_times_fun() if route == "base-y-pi"
             else dyn.regressor_transpose_times_fun())
        ins = f.sx_in()   # same expression under the study's function name
        return ca.Function(name, ins, f.call(ins), f.name_in(), f.name_out(), {"cse": True})
    if route in ("explicit", "matrix-free", "recursive"):
        mech = Mechanics(model, model.nominal)
        return ca.Function(name, [mech.q, mech.qd, mech.qd_r, mech.qdd_r],
                           [mech.slotine_li(route)], ["q", "qd", "qd_r", "qdd_r"], ["tau"],
                           {"cse": True})
    lin = LinearParameters(model)
    return {"y-delta": lin.regressor_times_fun, "yt-s": lin.regressor_transpose_times_fun,
            "y-formed": lin.regressor_fun}[route](name)


def measure_route(n: int, route: str, *, compile: bool = True, time_c: bool = True,
                  calls: int = 20000) -> dict:
    """Size and speed of ``Mechanics.slotine_li(route)`` for :func:`chain_model` (n).

    Builds τ = B q̈_r + C q̇_r + G at nominal values as a ``casadi.Function`` of
    ``q, qd, qd_r, qdd_r`` with ``{"cse": True}``, generates C for it, and
    optionally compiles and times it.

    Parameters
    ----------
    n
        Number of links.
    route
        A key of :data:`ROUTES`.
    compile
        Compile the C into a shared library (gcc -O3 -fPIC -shared).
    time_c
        Time the function in a C loop with :func:`~softgen.codegen.cbench.time_in_c`.
    calls
        Calls per timed repeat.

    Returns
    -------
    dict
        ``n, route, build_seconds, instructions, c_bytes, generate_seconds,
        compile_seconds`` (None if not compiled), ``ns_per_call`` (None if not timed).

    Raises
    ------
    BuildError
        No compiler, or compiling failed (also when over the memory or time cap).
    """
    if route not in ROUTES:
        raise ValueError(f"route: expected one of {', '.join(ROUTES)}, got {route!r}")
    model = chain_model(n)
    name = f"{route.replace('-', '_')}_{n}"

    t0 = time.perf_counter()
    f = _route_function(model, route, name)
    build_seconds = time.perf_counter() - t0

    row: dict[str, Any] = {"n": n, "route": route, "build_seconds": build_seconds,
                           "instructions": int(f.n_instructions())}
    with tempfile.TemporaryDirectory(prefix="softgen-chains-") as tmp:
        t0 = time.perf_counter()
        gen = ca.CodeGenerator(f"{name}.c", {"with_header": True})
        gen.add(f)
        gen.generate(tmp + "/")   # CodeGenerator joins prefix and file name as strings
        row["generate_seconds"] = time.perf_counter() - t0
        c_file = Path(tmp) / f"{name}.c"
        row["c_bytes"] = c_file.stat().st_size
        lib = Path(tmp) / f"lib{name}.so"
        row["compile_seconds"] = (
            compile_shared(c_file, lib, timeout=COMPILE_TIMEOUT,
                           memory_bytes=COMPILE_MEMORY_BYTES) if compile else None)
        # The timing harness links to the library just built: each route compiles once.
        row["ns_per_call"] = (time_in_c(c_file, [name], calls=calls,
                                        library=lib if compile else None)[name]
                              if time_c else None)
    return row


def scaling_table(ns=(2, 5, 10, 20, 40), routes=("explicit", "matrix-free"), *,
                  max_explicit_n: int = 10, **kw) -> list[dict]:
    """:func:`measure_route` for every ``n`` in ``ns`` and every route in ``routes``.

    The quadratic routes (:data:`QUADRATIC`) are not measured above
    ``max_explicit_n``: their expressions grow about quadratically and gcc -O3 on it becomes the bottleneck (time and
    memory). Such points are recorded as ``{"n", "route", "skipped": reason}``;
    a point whose compilation fails is recorded with ``"error"`` so the rest of
    the table is kept.

    Parameters
    ----------
    ns, routes
        Chain lengths and routes to measure.
    max_explicit_n
        Largest n for which the quadratic routes are measured.
    **kw
        Passed to :func:`measure_route` (``compile``, ``time_c``, ``calls``).
    """
    rows: list[dict] = []
    for n in ns:
        for route in routes:
            if route in QUADRATIC and n > max_explicit_n:
                rows.append({"n": n, "route": route,
                             "skipped": f"quadratic route above n = {max_explicit_n}"})
                continue
            try:
                rows.append(measure_route(n, route, **kw))
            except BuildError as exc:
                rows.append({"n": n, "route": route, "error": str(exc).splitlines()[0]})
    return rows


_COLUMNS = (  # key, header, format
    ("n", "n", "{}"),
    ("route", "route", "{}"),
    ("instructions", "instructions", "{}"),
    ("c_bytes", "C bytes", "{}"),
    ("build_seconds", "build s", "{:.3f}"),
    ("generate_seconds", "generate s", "{:.3f}"),
    ("compile_seconds", "compile s", "{:.2f}"),
    ("ns_per_call", "ns/call", "{:.1f}"),
)


def format_table(rows: list[dict]) -> str:
    """Aligned plain-text table of :func:`scaling_table` rows.

    Missing values print as ``-``; skipped or failed points carry their reason
    in a last ``note`` column.
    """
    header = [h for _, h, _ in _COLUMNS] + ["note"]
    body = []
    for row in rows:
        cells = [fmt.format(row[key]) if row.get(key) is not None else "-"
                 for key, _, fmt in _COLUMNS]
        cells.append(row.get("skipped") or row.get("error") or "")
        body.append(cells)
    widths = [max(len(r[i]) for r in [header, *body]) for i in range(len(header))]
    # Text columns (route, note) left-aligned, numbers right-aligned.
    left = {1, len(header) - 1}

    def line(cells: list[str]) -> str:
        return "  ".join(c.ljust(w) if i in left else c.rjust(w)
                         for i, (c, w) in enumerate(zip(cells, widths))).rstrip()

    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, body)])
