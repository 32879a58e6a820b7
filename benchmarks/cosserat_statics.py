"""Convergence of Cosserat statics with the number of segments and the GVS order (issue 33).

A horizontal cantilever of length 1 m with EI = 1 N m² (bending only, inextensible),
under a tip load P L²/EI = 2 or its weight w L³/EI = 2, against the planar elastica
(``tests/elastica_reference.py``, scipy BVP at 1e-10): the tip's distance from the
elastica's, as a fraction of the length, for PCS (order 0) with 1-20 segments and GVS
of order 1-4 with 1-3 segments, with the number of configuration variables.

    .venv/bin/python benchmarks/cosserat_statics.py
"""
from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from elastica_reference import tip as elastica_tip  # noqa: E402

from softgen.app.statics import Loads, Statics  # noqa: E402
from softgen.modelfile.load import load_model  # noqa: E402

L, EI, R = 1.0, 1.0, 0.01


def model(segments: int, order: int, weight: float, where: Path):
    rho = weight / (math.pi * R * R * 9.81) if weight else 1.0
    seg = (f"[[segments]]\nlength = {L / segments!r}\nradius = {R}\ndensity = {rho!r}\n"
           f"EI = {EI}\nstrains = [\"bend_y\"]\norder = {order}\n")
    g = [0.0, 0.0, -9.81] if weight else [0.0, 0.0, 0.0]
    p = where / f"c{segments}_{order}_{int(weight > 0)}.toml"
    p.write_text(f"[model]\nname = \"c\"\nkind = \"cosserat\"\n[gravity]\nvector = {g}\n"
                 + seg * segments)
    return load_model(p)


def main() -> None:
    where = Path(tempfile.mkdtemp())
    refs = {"tip": elastica_tip(L, EI, P=(0.0, -2.0)), "weight": elastica_tip(L, EI, q=(0.0, -2.0))}
    rows = [(n, 0) for n in (1, 2, 5, 10, 20)] + \
        [(n, k) for k in (1, 2, 3, 4) for n in (1, 2, 3)]
    print("| segments | order | DoF | tip load P L²/EI = 2 | weight w L³/EI = 2 |")
    print("|---:|---:|---:|---:|---:|")
    for n, k in rows:
        errs = []
        for case, ref in refs.items():
            m = model(n, k, 2.0 if case == "weight" else 0.0, where)
            loads = Loads(tip_force=(0.0, 0.0, -2.0)) if case == "tip" else Loads()
            res = Statics(m).solve(loads)
            errs.append(float(np.linalg.norm(res.tip_position[[0, 2]] - ref)) / L)
        print(f"| {n} | {k} | {m.dof} | {errs[0]:.2e} | {errs[1]:.2e} |", flush=True)


if __name__ == "__main__":
    main()
