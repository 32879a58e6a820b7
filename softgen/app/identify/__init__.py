"""``softgen identify``: model parameters from data (issue 24 item 3).

Three jobs, each a function here and a mode of the verb:

:func:`identify_model`
    base inertial parameters plus viscous and Coulomb friction per joint from a log
    of q and τ (or motor currents), :mod:`softgen.app.identify.rigid`; writes the
    identified model file (:mod:`softgen.app.identify.modelfile`).
:func:`identify_actuator`
    the thesis's actuator characterisations: the qbmove sinh spring (§6.2.4.1) and
    the McKibben force map (§2.1), :mod:`softgen.app.identify.actuator`.
:func:`excite`
    an optimised Fourier-series excitation trajectory for a model
    (:mod:`softgen.studies.excitation`), written as CSV.
"""
from __future__ import annotations

import json
import math
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from softgen.app.identify.actuator import ActuatorFit, identify_actuator
from softgen.app.identify.modelfile import (identified_name, model_tables, to_toml,
                                            write_text_atomic, write_trajectory_csv)
from softgen.app.identify.rigid import (BASE_WRENCH_COLUMNS, MIN_EXPLAINED,
                                        RigidIdentification, check_log, identify_rigid,
                                        read_identification_log, unit_hints)
from softgen.core.errors import ModelError, SoftgenError
from softgen.modelfile.model import RobotModel
from softgen.modelfile.limits import HARMONICS, LOG_ROWS
from softgen.modelfile.load import as_model, load_model
from softgen.studies.excitation import (Excitation, IdentificationRegressor, joint_limits,
                                        optimise_excitation)

__all__ = ["ActuatorFit", "RigidIdentification", "identify_actuator", "identify_model",
           "excite", "report_lines", "write_identified_model"]


def _rigid(model_name) -> RobotModel:
    model = as_model(model_name)           # a name, a file or a loaded chain
    if not isinstance(model, RobotModel):
        raise SoftgenError(f"{model.name}: identify needs a rigid model (links and joints); "
                           "soft bodies are not supported")
    return model


def default_out(log: Path, model: RobotModel) -> Path:
    return log.with_name(f"{identified_name(model)}.toml")


def identify_model(model_name, log: str | Path, *, out: str | Path | None = None,
                   force: bool = False, cutoff: float | None = None,
                   torque_constant: list[float] | None = None, viscous: bool = True,
                   coulomb: bool = True) -> tuple[RigidIdentification, Path]:
    """Identify ``model`` from ``log`` and write the identified model file.

    The output is checked for existence before any work (``--force`` to overwrite).
    """
    model = _rigid(model_name)
    log = Path(log)
    out = Path(out) if out is not None else default_out(log, model)
    if out.exists() and not force:
        raise SoftgenError(f"--out {out}: exists; give --force to overwrite it")
    data = read_identification_log(log, model.dof, torque_constant=torque_constant,
                                   floating=model.floating)
    check_log(data, model)
    options = {"cutoff": cutoff, "viscous": viscous, "coulomb": coulomb}
    res = identify_rigid(model, data, **options)
    problem = implausible(res)
    if problem:
        fits = not res.explained.size or res.explained.min() >= MIN_EXPLAINED
        hints = unit_hints(data, model, res) if fits else []
        raise SoftgenError("; ".join([f"identify: {log}: {problem}", *hints,
                                      *swap_hint(model, data, res, options)]))
    write_identified_model(res, out, log=log, force=force)
    return res, out


def implausible(res: RigidIdentification) -> str | None:
    """Why the identification must not be written (None when it may): a fit that explains
    too little of the torque, or physical values that no model file may hold."""
    worst = int(np.argmin(res.explained)) if res.explained.size else 0
    if res.explained.size and not res.explained[worst] >= MIN_EXPLAINED:
        # A floating base's rows are its wrench (fx..mz) and then the joints' torques.
        what = (f"joint {worst + 1}'s torque" if not res.model.floating else
                f"the base wrench's {BASE_WRENCH_COLUMNS[worst]}" if worst < 6 else
                f"joint {worst - 5}'s torque")
        return (f"the model explains {100 * max(res.explained[worst], 0.0):.1f} % of {what} "
                f"(at least {100 * MIN_EXPLAINED:.0f} % expected): q and "
                "tau do not belong together (noise, swapped columns, or another robot's log)")
    if res.violations:
        return (f"the identified values are not physical ({res.violations[0]}"
                + (f", and {len(res.violations) - 1} more" if len(res.violations) > 1 else "")
                + "); nothing written")
    return None


def swap_hint(model: RobotModel, data, res: RigidIdentification, options: dict) -> list[str]:
    """``["... swapped ..."]`` when the log identifies clearly better with its q and tau
    columns exchanged, else ``[]`` (also on a floating base: its q and τ differ in size)."""
    if model.floating:
        return []
    swapped = replace(data, q=data.tau, tau=data.q)
    try:
        check_log(swapped, model)
        other = identify_rigid(model, swapped, **options)
    except (SoftgenError, ValueError, np.linalg.LinAlgError):
        return []
    if implausible(other) is None and other.explained.min() > res.explained.min() + 0.05:
        return [f"with q and tau exchanged the log fits (R^2 {other.explained.min():.3f} "
                f"against {res.explained.min():.3f}) and is physical: are the columns "
                "swapped?"]
    return []


def write_identified_model(res: RigidIdentification, out: str | Path, *, log: Path | None = None,
                           force: bool = False) -> Path:
    """The identified model file (module :mod:`~softgen.app.identify.modelfile`)."""
    model = res.model
    values = {**model.nominal, **res.physical}
    fv = res.friction("fv")
    damping = {j: v for j, v in fv.items() if v >= 0}
    tables = model_tables(model, values, damping=damping, name=identified_name(model))
    comments = [f"Identified by softgen identify from {log if log is not None else 'a log'}",
                f"(model {model.name}). Values of the uncertain parameters below are the "
                "physical values closest",
                "to the original model's that reproduce the identified base parameters; "
                "viscous friction is the links' damping."] + [""] + report_lines(res)
    text = to_toml(tables, comments)
    check_loadable(text, out)
    return write_text_atomic(out, text, force=force)


def check_loadable(text: str, out: Path) -> None:
    """Refuse to write a model file that ``softgen info`` would refuse: ``text`` is read
    back by the model loader first (issue 36: ``mass = -12.16`` was written)."""
    with tempfile.TemporaryDirectory(prefix="softgen-identify-") as tmp:
        path = Path(tmp) / Path(out).name
        path.write_text(text)
        try:
            load_model(path)
        except ModelError as exc:
            msg = str(exc).replace(str(path), str(out)).splitlines()[0]
            raise SoftgenError(f"identify: the identified model would not load ({msg}); "
                               "nothing written") from None


def report_lines(res: RigidIdentification) -> list[str]:
    """Human-readable summary: the estimates ± σ and the checks."""
    lines = [f"{res.samples} samples per joint after filtering (cut-off {res.cutoff_hz:.4g} Hz, "
             f"decimation {res.decimation}, log dt {res.dt:.6g} s, torque from "
             f"{res.torque_source})",
             f"condition number of the weighted data matrix {res.condition:.4g} "
             f"(unit-norm columns {res.condition_scaled:.4g})",
             "residual rms per joint [N m]: "
             + ", ".join(f"{v:.4g}" for v in res.residual_rms),
             "", "parameter          estimate        std         rel. std   nominal   "
             "(combination)"]
    for name, e, s, r, nom, ex in zip(res.names, res.estimate, res.std, res.relative_std,
                                       res.nominal, res.expressions):
        lines.append(f"{name:<18} {e: .6e} {s: .3e} {r:9.3g} % {nom: .4e}   {ex}")
    lines.append("")
    if res.projected_from:
        lines.append("the physical values nearest the model's that give these base parameters "
                     "are not consistent:")
        lines += [f"  {v}" for v in res.projected_from]
        lines.append("so the model file holds the consistent values (log-Cholesky projection) "
                     "that fit them best: its base parameters differ from the estimates by at "
                     f"most {res.projection_misfit:.3g} sigma")
    if res.violations:
        lines.append("physically consistent: NO")
        lines += [f"  {v}" for v in res.violations]
    else:
        lines.append("physically consistent: yes (positive masses, inertias about the centres "
                     "of mass positive definite with the triangle inequality)")
    negative = [f"{n} = {v:.4g}" for n, v in zip(res.names, res.estimate)
                if n.startswith(("fv", "fc")) and v < 0]
    if negative:
        lines.append("negative friction (not written to the model): " + ", ".join(negative))
    return lines


@dataclass
class ExciteResult:
    excitation: Excitation
    out: Path
    samples: int
    seconds: float


def excite(model_name, out: str | Path, *, harmonics: int = 5,
           period: float = 10.0, dt: float = 1e-3, periods: int = 1, seed: int = 0,
           maxiter: int = 100, grid: int = 100, viscous: bool = True, coulomb: bool = True,
           force: bool = False) -> ExciteResult:
    """An optimised excitation trajectory for ``model`` written to ``out`` (CSV)."""
    check_excitation_options(harmonics=harmonics, period=period, dt=dt, periods=periods,
                             maxiter=maxiter)
    model = _rigid(model_name)
    if model.floating:
        raise SoftgenError(f"{model.name}: --excite plans joint trajectories within joint "
                           "limits for a fixed base; a floating base's motion is not commanded")
    out = Path(out)
    if out.exists() and not force:
        raise SoftgenError(f"--out {out}: exists; give --force to overwrite it")
    t0 = time.perf_counter()
    reg = IdentificationRegressor(model, viscous=viscous, coulomb=coulomb)
    ex = optimise_excitation(reg, harmonics=harmonics, period=period,
                             limits=joint_limits(model), grid=grid, seed=seed, maxiter=maxiter)
    write_trajectory_csv(out, ex.trajectory, dt=dt, periods=periods, force=force)
    return ExciteResult(ex, out, int(round(periods * period / dt)),
                        time.perf_counter() - t0)


#: Samples per cycle of the highest harmonic a written trajectory must have.
SAMPLES_PER_CYCLE = 10


def _count(value, flag: str, least: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < least:
        raise SoftgenError(f"identify: {flag}: expected an integer of at least {least}, "
                           f"got {value!r}")
    return value


def check_excitation_options(*, harmonics: int, period: float, dt: float, periods: int,
                             maxiter: int) -> int:
    """Every ``--excite`` option checked before the optimisation runs; returns the rows
    the trajectory will have. One line each (issue 36: ``--dt 100`` wrote "0 samples"
    with status 0, ``--period 1e9`` failed allocating 7 TiB after the optimisation,
    ``--harmonics 100000`` after 21.6 CPU-s)."""
    HARMONICS.check(_count(harmonics, "--harmonics", 1), "identify: --harmonics")
    _count(periods, "--periods", 1)
    _count(maxiter, "--maxiter", 0)
    for flag, v in (("--period", period), ("--dt", dt)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (
                math.isfinite(v) and v > 0):
            raise SoftgenError(f"identify: {flag}: expected a positive number of seconds, "
                               f"got {v!r}")
    longest = period / (SAMPLES_PER_CYCLE * harmonics)
    if dt > longest:
        raise SoftgenError(f"identify: --dt {dt:g} s: {harmonics} harmonics over a {period:g} s "
                           f"period need at least {SAMPLES_PER_CYCLE} samples per cycle of the "
                           f"highest, so --dt at most {longest:.3g} s")
    return LOG_ROWS.check(periods * period / dt, f"identify: --excite: {periods} period(s) "
                          f"of {period:g} s every {dt:g} s")


def fit_lines(fit: ActuatorFit) -> list[str]:
    lines = [f"{fit.kind} fit of {fit.samples} samples (columns {', '.join(fit.columns)}):"]
    for n, v, s, u in zip(fit.names, fit.values, fit.std, fit.units):
        lines.append(f"  {n:<15} {v:.6g} ± {s:.2g} {u}")
    lines.append(f"  RMSRE {fit.rmsre_percent:.4g} % over {fit.rmsre_samples} samples "
                 f"(|measurement| >= 5 % of its maximum; thesis 6.2.4.1), rms error "
                 f"{fit.rms_error:.4g}")
    return lines


def fit_json(fit: ActuatorFit) -> str:
    return json.dumps(fit.as_dict(), indent=2) + "\n"

