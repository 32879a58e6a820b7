"""Files ``softgen identify`` writes: the identified model file, trajectories.

The identified model is written as a model file (TOML, the format of ``models/*.toml``).

The tables are rebuilt from the validated :class:`~softgen.modelfile.model.RobotModel`
(so a URDF model gives an equivalent ``kind = "spatial"`` TOML file) with every
parameter value taken from ``values`` (the nominal ones overridden by the
identified ones); viscous friction becomes the links' ``damping``. A comment block
at the top records the base-parameter estimates ± σ, the friction, the data's
condition number and the physical-consistency check. The file is written to a
temporary file and renamed into place, never over an existing file without ``force``.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from softgen.core.errors import SoftgenError
import numpy as np

from softgen.modelfile.laws import DEFAULT_DEFLECTION_MAX
from softgen.modelfile.model import MAX_NAME, RobotModel
from softgen.core.atomic import atomic_open, write_text
from softgen.studies.excitation import FourierTrajectory


def model_tables(model: RobotModel, values: dict[str, float], *,
                 damping: dict[int, float] | None = None, name: str | None = None) -> dict:
    """The TOML tables of ``model`` at parameter ``values`` (name -> number)."""
    damping = damping or {}

    def v(x):
        return float(model.resolve(x, values))

    meta = {"name": name or model.name, "kind": model.kind,
            "description": model.description, "source": model.source}
    if model.floating:
        meta["floating"] = True
    links = []
    # A tree's bodies in the order of the file they came from (their parameter names
    # m<i> number them so): parents first, and the same canonical names when read back.
    bodies = _file_order(model)
    base = model.base.name if model.base is not None else "base"
    for i, link in enumerate(bodies, start=1):
        t: dict = {"name": link.name, "joint": link.joint}
        if model.is_tree:
            par = model.parent_of(model.bodies.index(link))
            t["parent"] = base if par < 0 else model.bodies[par].name
        if model.kind == "planar":
            t["length"] = v(f"l{i}")
            t["mass"] = v(link.mass)
            t["com"] = v(link.com[0]) if link.com[1] == 0.0 else [v(link.com[0]), v(link.com[1])]
            t["inertia"] = v(link.inertia[2])
        else:
            t["axis"] = [float(a) for a in link.axis]
            t["origin_xyz"] = [v(x) for x in link.origin_xyz]
            t["origin_rpy"] = [float(a) for a in link.origin_rpy]
            t["mass"] = v(link.mass)
            t["com"] = [v(x) for x in link.com]
            t["inertia"] = [v(x) for x in link.inertia]
        if link.inertia_about != "com":
            t["inertia_about"] = link.inertia_about
        if link.mimic is not None:
            k, mult, off = link.mimic
            t["mimic"] = {"joint": model.links[k].name, "multiplier": mult, "offset": off}
        coord = model.links.index(link) if link in model.links else None
        d = damping.get(coord) if coord is not None else None
        if link.damping is not None or d is not None:
            t["damping"] = (v(link.damping) if link.damping is not None else 0.0) + (d or 0.0)
        if link.stiffness is not None:
            t["stiffness"] = v(link.stiffness)
        links.append(t)
    data: dict = {"model": meta}
    if model.kind == "planar":
        meta["base_angle_deg"] = math.degrees(model.base_rpy[2])
        data["gravity"] = {"g": values.get("g", model.nominal["g"])}
    else:
        g = values.get("g", model.nominal["g"])
        data["gravity"] = {"vector": [g * c for c in model.gravity_direction]}
    if model.is_tree or model.floating:
        data["base"] = {"name": base}
        if model.base is not None:
            b = model.base
            data["base"].update({"mass": v(b.mass), "com": [v(x) for x in b.com],
                                 "inertia": [v(x) for x in b.inertia]})
            if b.inertia_about != "com":
                data["base"]["inertia_about"] = b.inertia_about
    data["links"] = links
    if model.actuators:
        names = [link.name for link in model.links]
        data["actuators"] = [_actuator_table(a, names) for a in model.actuators]
    data["parameters"] = {"uncertain": list(model.uncertain)}
    return data


def _file_order(model: RobotModel) -> list:
    """``model.bodies`` in the order of their file (the index in their mass parameter's
    name, m<i>); the model's order when a mass is not a parameter name."""
    def index(link):
        m = link.mass
        return int(m[1:]) if isinstance(m, str) and m[1:].isdigit() else None
    keys = [index(link) for link in model.bodies]
    if any(k is None for k in keys):
        return list(model.bodies)
    return [link for _, link in sorted(zip(keys, model.bodies), key=lambda x: x[0])]


def _actuator_table(a, names: list[str]) -> dict:
    """One ``[[actuators]]`` entry as the model file writes it: the named instances
    (``mckibben``, ``qbmove``) by their keys, declared laws (``sea``, ``antagonistic``)
    with their law and constants, ``[actuators.a]``/``[actuators.b]`` for a pair."""
    t: dict = {"joint": names[a.joint], "type": a.type}
    if a.type == "direct":
        return t
    # A declared deflection range of spring laws (default 1 rad) is kept.
    dmax = {d for sd in a.sides if sd.law.drive == "spring"
            and (d := sd.law.deflection_max) != DEFAULT_DEFLECTION_MAX}
    if dmax:
        t["deflection_max"] = dmax.pop()
    if a.type in ("mckibben", "qbmove"):
        return {**t, **{k: (list(x) if isinstance(x, tuple) else x) for k, x in a.values}}
    # SEA motor values are stored as 1-tuples, a pair's as (a side, b side).
    values = {k: (x[0] if isinstance(x, tuple) and len(x) == 1 else
                  list(x) if isinstance(x, tuple) else x) for k, x in a.values}
    if a.type == "sea":
        (side,) = a.sides
        return {**t, **values, "law": side.text, **dict(side.constants)}
    return {**t, "drive": a.drive, **values,
            **{sd.name: {"law": sd.text, **dict(sd.constants)} for sd in a.sides}}


def _value(x) -> str:
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, int):
        return str(x)
    if isinstance(x, float):
        if not math.isfinite(x):
            raise SoftgenError(f"identified model: non-finite value {x!r} cannot be written")
        return repr(x)
    if isinstance(x, str):
        return json.dumps(x, ensure_ascii=False)     # a valid TOML basic string
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(_value(e) for e in x) + "]"
    raise SoftgenError(f"identified model: cannot write {type(x).__name__} to TOML")


def to_toml(data: dict, comments: list[str] = ()) -> str:
    """TOML text of ``data`` (tables and arrays of tables of scalars and lists)."""
    out = [f"# {c}" if c else "#" for c in comments]
    for key, table in data.items():
        if isinstance(table, dict):
            out += ["", f"[{key}]"] + [f"{k} = {_value(x)}" for k, x in table.items()]
        elif isinstance(table, list) and table and all(isinstance(t, dict) for t in table):
            for t in table:
                out += ["", f"[[{key}]]"] + [f"{k} = {_value(x)}" for k, x in t.items()
                                             if not isinstance(x, dict)]
                for sub, st in t.items():      # sub-tables of this entry, after its keys
                    if isinstance(st, dict):
                        out += [f"[{key}.{sub}]"] + [f"{k} = {_value(x)}" for k, x in st.items()]
        else:
            out.insert(len(comments), f"{key} = {_value(table)}")
    return "\n".join(out) + "\n"


def identified_name(model: RobotModel) -> str:
    name = f"{model.name}_identified"
    return name if len(name) <= MAX_NAME else name[:MAX_NAME]


def write_text_atomic(path: str | Path, text: str, *, force: bool = False,
                      flag: str = "--out") -> Path:
    """Write ``text`` to a temporary file beside ``path`` and rename it into place."""
    path = Path(path)
    if path.exists() and not force:
        raise SoftgenError(f"{flag} {path}: exists; give --force to overwrite it")
    if path.is_dir():
        raise SoftgenError(f"{flag} {path}: is a directory; give a file name")
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise SoftgenError(f"{flag} {path}: directory {directory} does not exist")
    return write_text(path, text)


def write_trajectory_csv(path: str | Path, traj: FourierTrajectory, *, dt: float,
                         periods: int = 1, force: bool = False) -> Path:
    """Write t, q*, qd*, qdd* sampled every ``dt`` over ``periods`` periods, atomically.

    Refuses to overwrite an existing file unless ``force``.
    """
    path = Path(path)
    if path.exists() and not force:
        raise SoftgenError(f"--out {path}: exists; give --force to overwrite it")
    if not dt > 0:
        raise SoftgenError(f"--dt: expected a positive sample time, got {dt!r}")
    K = int(round(periods * traj.period / dt))
    t = np.arange(K) * dt
    q, qd, qdd = traj.evaluate(t)
    n = q.shape[1]
    header = (["t"] + [f"q{i + 1}" for i in range(n)] + [f"qd{i + 1}" for i in range(n)]
              + [f"qdd{i + 1}" for i in range(n)])
    table = np.hstack([t[:, None], q, qd, qdd])
    write_csv_atomic(path, header, table)
    return path


def write_csv_atomic(path: Path, header: list[str], table: np.ndarray) -> None:
    """A CSV file (full precision) written to a temporary file and renamed into place."""
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise SoftgenError(f"--out {path}: directory {directory} does not exist")
    with atomic_open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in table:
            w.writerow([repr(float(v)) for v in row])
