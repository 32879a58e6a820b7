"""Named casadi.Functions -> ``<name>.c``, ``<name>.h`` and ``manifest.json``.

This module knows nothing of robots: it takes a bundle name, the functions with
one-line docs, the parameter vector they use, and the bytes that identify what
produced them, and writes the bundle in one pass (acados ``GenerateContext``
convention, docs/design.md section 3 item 3). The manifest is the contract of
docs/design.md section 2; it is extended (never changed) with ``source_sha256``,
``instructions``, ``parameters.expressions`` and ``softgen_version``.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca

from softgen.codegen.build import clean_orphans, library_name
from softgen.codegen.schedule import apply_orders
from softgen.core.atomic import OutputError, write_set
from softgen.core.errors import SoftgenError

#: Bumped whenever the generated code for the same model would change.
# 2: issue 22 (declared actuators, sampled Theorem 10, multi-DoF UIO)
# 3: issue 25 (per-function compiler levels, Generated.optimization)
# 4: issue 35 (the recursion's Slotine-Li tau carries beta = alpha - omega x omega_r;
#    trees' tau in push order, Generated.order)
CODEGEN_VERSION = "4"

CODEGEN_OPTS = {"with_header": True}


@dataclass(frozen=True)
class Generated:
    """One function to emit: the casadi.Function and a one-line description.

    ``optimization``: the compiler level of this function's C when it differs from
    the bundle's (None: the bundle's). ``order``: the order in which its C computes its
    values (:mod:`softgen.codegen.schedule`; None: CasADi's).
    """

    function: ca.Function
    doc: str
    optimization: str | None = None
    order: ca.Function | None = None


@dataclass
class BundleSpec:
    """Everything a bundle is made of."""

    name: str
    functions: list[Generated]
    parameters: dict = field(default_factory=lambda: {"names": [], "nominal": []})
    identity: bytes = b""          # model file bytes + options: what the hash covers
    extra: dict = field(default_factory=dict)   # extra manifest keys (e.g. "model_file")
    optimization: str = "-O3"      # compiler level; recorded in the manifest when not -O3
    #: Loop functions (``mapaccum`` of a per-sample function) to emit as a plain C loop:
    #: loop name -> the function it repeats (see :func:`_plain_loop`).
    loops: dict[str, ca.Function] = field(default_factory=dict)
    #: Batch drivers to emit (plain C, not CasADi's calling convention): driver name ->
    #: the per-sample function it repeats, which must be one of ``functions`` (see
    #: :func:`batch_driver`).
    batches: dict[str, ca.Function] = field(default_factory=dict)


def content_hash(identity: bytes) -> str:
    """sha256 of what produced the bundle, the CasADi version and softgen's codegen version."""
    h = hashlib.sha256()
    h.update(identity)
    h.update(f"\ncasadi={ca.__version__}\ncodegen={CODEGEN_VERSION}\n".encode())
    return h.hexdigest()


def signature(f: ca.Function) -> dict:
    def shape(sp: ca.Sparsity) -> list[int]:
        return [int(sp.size1()), int(sp.size2())]

    return {
        "inputs": [{"name": f.name_in(i), "shape": shape(f.sparsity_in(i))}
                   for i in range(f.n_in())],
        "outputs": [{"name": f.name_out(i), "shape": shape(f.sparsity_out(i))}
                    for i in range(f.n_out())],
    }


def _can_fail(f: ca.Function) -> bool:
    """Whether the generated C can return non-zero.

    CasADi emits SX functions as straight-line code whose only exit is
    ``return 0``; anything else (MX graphs, maps, calls) may propagate a code.
    """
    return not f.is_a("SXFunction")


#: The first line of each function CasADi emits (``/* name:(inputs)->(outputs) */``).
_HEADING = re.compile(rb"^/\* [A-Za-z_][A-Za-z0-9_]*:\(", re.M)
_GNU = b"#if defined(__GNUC__) && !defined(__clang__)\n"


def with_levels(c_src: bytes, names: list[str], levels: dict[str, str]) -> bytes:
    """``c_src`` with the functions of ``levels`` compiled at their own level.

    Each named function's stretch of the file (its helpers, first emitted for it, the
    exported wrapper and its work functions) is wrapped in ``#pragma GCC
    push_options``/``optimize``/``pop_options``; compilers other than gcc skip the
    pragmas (guarded), so the file stays standalone C. ``names``: every exported
    function of the file, in the order they were added to the code generator. A function
    an earlier one calls (a composed loop's plant) was emitted as that one's helper, at
    its level; its own stretch holds only its wrappers, left as they are.
    """
    out, pos = [], 0
    for name in names:
        m = re.search(rb"CASADI_SYMBOL_EXPORT int " + name.encode() + rb"_work_bytes\(",
                      c_src[pos:])
        if m is None:
            raise ValueError(f"{name}: no {name}_work_bytes in the generated C")
        end = c_src.index(b"\n}\n", pos + m.end()) + 3
        level = levels.get(name)
        head = _HEADING.search(c_src, pos, end) if level is not None else None
        if level is not None and head is not None:
            start = head.start()
            out += [c_src[pos:start],
                    b"/* softgen: compiled at " + level.encode() + b" (Generated.optimization)"
                    b" */\n" + _GNU + b"#pragma GCC push_options\n"
                    b"#pragma GCC optimize (\"" + level.lstrip("-").encode() + b"\")\n"
                    b"#endif\n", c_src[start:end],
                    _GNU + b"#pragma GCC pop_options\n#endif\n"]
        else:
            out.append(c_src[pos:end])
        pos = end
    out.append(c_src[pos:])
    return b"".join(out)


def _plain_loop(c_src: bytes, loop: ca.Function, sample: ca.Function) -> bytes:
    """``loop`` (N samples of ``sample`` by ``mapaccum``) re-emitted as a plain C loop.

    ``loop``: ``(x0 (nx), p, k0 (1), E (ne × N)) -> (X (nx × N), Y (ny × N))``,
    ``sample``: ``(xa = (x, k), p, e) -> (xa_next, y)``. CasADi builds ``mapaccum`` as a
    tower of nested unrolled calls (10 per level) that copies the state and the
    recorded signals into a work vector at every level and repeats ``p`` N times, so
    every recorded signal costs memory traffic per level (issue 25: Theorem 5's loop
    ran at ~2,300x real time recording 7 signals against ~3,000x recording q, in CPU
    time). Here the same ``sample`` code is called once per sample, writing y straight
    into the output column and x into X; the state moves by pointer swap. The CasADi
    function is unchanged (its API, sizes, names; the CasADi backend evaluates the
    tower); only its exported entry point calls this loop. Same operations in the same
    order on every sample: the numbers are the same.
    """
    n_x = sample.sparsity_in(0).nnz() - 1
    n_p, n_e = sample.sparsity_in(1).nnz(), sample.sparsity_in(2).nnz()
    n_y, steps = sample.sparsity_out(1).nnz(), loop.sparsity_out(1).size2()
    shapes = ([loop.sparsity_in(i).size() for i in range(4)],
              [loop.sparsity_out(i).size() for i in range(2)])
    if (loop.n_in(), loop.n_out(), sample.n_in(), sample.n_out()) != (4, 2, 3, 2) or \
            shapes != ([(n_x, 1), (n_p, 1), (1, 1), (n_e, steps)],
                       [(n_x, steps), (n_y, steps)]) or \
            not all(sample.sparsity_in(i).is_dense() for i in range(3)) or \
            not all(sample.sparsity_out(i).is_dense() for i in range(2)):
        raise ValueError(f"loops: {loop.name()} is not N samples of {sample.name()} "
                         "(x0, p, k0, E) -> (X, Y)")
    # The loop borrows the tower's work vectors, which hold every nested call's.
    n_a = n_x + 1
    if loop.sz_arg() < 4 + sample.sz_arg() or loop.sz_res() < 2 + sample.sz_res() or \
            loop.sz_iw() < sample.sz_iw() or loop.sz_w() < 2 * n_a + sample.sz_w():
        raise ValueError(f"loops: the work vectors of {loop.name()} are too small for "
                         f"a loop over {sample.name()}")
    name, fn = loop.name(), f"softgen_plain_{loop.name()}"
    entry = (f"CASADI_SYMBOL_EXPORT int {name}(const casadi_real** arg, casadi_real** res, "
             "casadi_int* iw, casadi_real* w, int mem){\n")
    text = c_src.decode()
    head, sep, rest = text.partition(entry)
    call, nl, tail = rest.partition("\n")
    if not sep or entry in tail or not (call.startswith("  return casadi_f")
                                        and call.endswith("(arg, res, iw, w, mem);")):
        raise ValueError(f"loops: no entry point of {name} in the generated C (a CasADi "
                         "version that emits it differently)")
    body = f"""/* {name}: {steps} samples of {sample.name()} in a plain loop (softgen). */
static int {fn}(const casadi_real** arg, casadi_real** res, casadi_int* iw, casadi_real* w, int mem) {{
  const casadi_real** a = arg + 4;
  casadi_real** r = res + 2;
  casadi_real *xa = w, *xb = w + {n_a}, *t;
  casadi_int i, j;
  for (i = 0; i < {n_x}; ++i) xa[i] = arg[0] ? arg[0][i] : 0;
  xa[{n_x}] = arg[2] ? arg[2][0] : 0;
  for (j = 0; j < {steps}; ++j) {{
    a[0] = xa;
    a[1] = arg[1];
    a[2] = arg[3] ? arg[3] + j * {n_e} : 0;
    r[0] = xb;
    r[1] = res[1] ? res[1] + j * {n_y} : 0;
    if ({sample.name()}(a, r, iw, w + {2 * n_a}, 0)) return 1;
    if (res[0]) for (i = 0; i < {n_x}; ++i) res[0][j * {n_x} + i] = xb[i];
    t = xa; xa = xb; xb = t;
  }}
  return 0;
}}

"""
    return (head + body + entry + f"  return {fn}(arg, res, iw, w, mem);" + nl + tail).encode()


def _emit(spec: BundleSpec) -> tuple[bytes, bytes]:
    """CasADi's C and header of the bundle's functions, written by its CodeGenerator
    into a temporary directory and read back. A full or unwritable temporary directory
    is one :class:`~softgen.core.atomic.OutputError` line naming it (issue 36: an
    OSError traceback, or CasADi's ``stream_ptr`` assertion)."""
    cg = ca.CodeGenerator(f"{spec.name}.c", CODEGEN_OPTS)
    for sample in spec.loops.values():    # defined before the loops that call them
        cg.add(sample)
    for g in spec.functions:
        cg.add(g.function)
    where = Path(tempfile.gettempdir())
    try:
        with tempfile.TemporaryDirectory() as tmp:
            where = Path(tmp)
            cg.generate(tmp + os.sep)
            return ((where / f"{spec.name}.c").read_bytes(),
                    (where / f"{spec.name}.h").read_bytes())
    except OSError as exc:
        if isinstance(exc, SoftgenError):
            raise
        raise OutputError(f"cannot write the generated C to {where}: "
                          f"{exc.strerror or exc}") from None
    except RuntimeError as exc:        # CasADi's C++ streams: no errno of their own
        free = _free_bytes(where)
        why = "No space left on device" if free is not None and free < (1 << 20) else \
            str(exc).splitlines()[0]
        raise OutputError(f"cannot write the generated C to {where}: {why} (set TMPDIR to "
                          "a directory with room)") from None


def _free_bytes(path: Path) -> int | None:
    try:
        return shutil.disk_usage(path if path.exists() else path.parent).free
    except OSError:
        return None


#: Functions of at least this many CasADi instructions are compiled at -O1 (model
#: bundles: ``softgen.bundles.bundle``; batch drivers: ``softgen.runtime.compiled``),
#: smaller ones at -O3 (issue 34: ``generate --all`` within 60 CPU-s of compiles). gcc's
#: time grows faster than the size of one straight-line function, and at this size -O3
#: buys little: ``benchmarks/function_levels.py`` (each function alone, compiled at -O1
#: and -O3, timed in C on the thread CPU clock; load 9-13 on 2 CPUs, so read the run-time
#: ratios to ±5 %), -O1 ÷ -O3: 3D PCC coriolis (13,447 instructions) time 1.03, compile
#: 0.41; forward dynamics (12,539) 1.07, 0.49; plant (9,420) 1.05, 0.58; inverse dynamics
#: (7,994) 0.99, 0.51; regressor (7,614) 1.06, 0.54; Panda Slotine-Li step (16,442) 1.07,
#: 0.49; coriolis (13,952) 1.01, 0.53; RK4 plant (13,563) 1.07, 0.52. Below it the arms'
#: regressors and dynamics gain 10-30 % at -O3 and the McKibben plants and Theorem 5 steps
#: 12-14 %, each compiled in a fraction of a second; a Theorem 5 sweep sample (1,165
#: instructions) runs 10 % fewer machine instructions at -O3 (callgrind: 2,677 against
#: 2,982 per sample, libm included).
LARGE_FUNCTION = 5000


def code_size(f: ca.Function) -> int:
    """The CasADi instructions of the largest straight-line (SX) function in ``f``'s C:
    ``f`` itself, or one it calls. What the :data:`LARGE_FUNCTION` rule is about (gcc's
    time grows faster than the size of one such function); an MX function (a composed
    loop, a looped plant) counts a call as one instruction, so its own count says nothing
    of the code it brings. The Cosserat rod's plant is 22 MX instructions around one
    ROS2 step of 23k lines of C, which the rule left at -O3: ``benchmarks/
    function_levels.py rod_tendon_3seg --functions rod_tendon_3seg_plant``, two runs at
    load 0.7-0.8, -O1 against -O3: compile 4.7 / 9.6 and 5.2 / 10.5 CPU-s, 8.3 / 7.6 and
    9.3 / 10.4 µs per call (the difference is the machine's noise); the bundle's gcc 19.0
    -> 15.1 CPU-s. Its forward dynamics, many small per-segment functions (7,157
    instructions in all, none large), stays at -O3: at -O1 they are not inlined (2.1-2.6
    against 1.8-1.9 µs)."""
    if f.is_a("SXFunction"):
        return f.n_instructions()
    return max([g.n_instructions() for g in f.find_functions() if g.is_a("SXFunction")],
               default=0)

#: Per run, what :func:`batch_driver` writes into ``info``: samples run, why the run ended
#: (:data:`BATCH_REASONS`), and the row of the first non-finite value (y rows first, then
#: the state's after them; -1 when none).
BATCH_INFO = 3
#: Why a batch run ended: it ran every sample, the stop row turned non-zero, or a value
#: turned non-finite.
BATCH_REASONS = ("end", "stop", "nonfinite")


def batch_driver(name: str, sample: ca.Function) -> str:
    """C of ``name``: many runs of the per-sample function ``sample``, one per column.

    ``sample``: ``(xa = (x, k), p, e) -> (xa_next, y)`` as a diagram's
    ``sample_fun`` (:meth:`softgen.blocks.ClosedLoop.sample_fun`). The driver (plain C,
    called through ctypes by :func:`softgen.runtime.simulate.simulate_batch`)::

        int name(const double *x0, const double *p, long long runs, double k0,
                 long long steps, long long stop_row, const double *e,
                 double *xf, double *info, long long *iw, double *w)

    runs ``runs`` closed loops one after the other, run b from state column b of
    ``x0`` (nx × runs) with parameter column b of ``p`` (np × runs), sample indices
    k0, k0 + 1, ... and external inputs ``e`` (ne × steps, shared by the runs; NULL:
    zeros). A run ends after ``steps`` samples, before the first sample at which row
    ``stop_row`` of y is non-zero (``stop_row`` < 0: never), or at the first non-finite
    value: in y at sample j (ended before it) or in the state after it (ended after
    it), the checks in that order, as :func:`softgen.runtime.simulate.simulate` orders
    them. Its state at the end goes to column b of ``xf``; :data:`BATCH_INFO` numbers
    to ``info``. ``iw``, ``w``: work of ``sample`` plus 2 (nx + 1) + ny + ne doubles.
    Each run starts afresh from its own columns, so its numbers do not depend on the
    others in the batch: a run of a batch equals the same run alone, to the bit.
    """
    n_x = sample.sparsity_in(0).nnz() - 1
    n_p, n_e = sample.sparsity_in(1).nnz(), sample.sparsity_in(2).nnz()
    n_y = sample.sparsity_out(1).nnz()
    if (sample.n_in(), sample.n_out()) != (3, 2) or \
            not all(sample.sparsity_in(i).is_dense() for i in range(3)) or \
            not all(sample.sparsity_out(i).is_dense() for i in range(2)) or \
            sample.sparsity_out(0).nnz() != n_x + 1:
        raise ValueError(f"batches: {sample.name()} is not a sample function "
                         "(xa, p, e) -> (xa_next, y)")
    n_a = n_x + 1
    sz_arg, sz_res = max(sample.sz_arg(), 3), max(sample.sz_res(), 2)
    return f"""
/* {name}: runs of {sample.name()}, one per column of x0 and p (softgen batch driver). */
CASADI_SYMBOL_EXPORT int {name}(const casadi_real* x0, const casadi_real* p, casadi_int runs,
    casadi_real k0, casadi_int steps, casadi_int stop_row, const casadi_real* e,
    casadi_real* xf, casadi_real* info, casadi_int* iw, casadi_real* w) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_real *xa, *xb, *t, *y = w + {2 * n_a}, *ez = w + {2 * n_a + n_y};
  casadi_real *ws = w + {2 * n_a + n_y + n_e};
  casadi_int b, i, j, reason, where;
  for (i = 0; i < {n_e}; ++i) ez[i] = 0;
  for (b = 0; b < runs; ++b) {{
    xa = w; xb = w + {n_a};
    for (i = 0; i < {n_x}; ++i) xa[i] = x0[b * {n_x} + i];
    xa[{n_x}] = k0;
    reason = 0; where = -1;
    for (j = 0; j < steps; ++j) {{
      arg[0] = xa; arg[1] = p + b * {n_p}; arg[2] = e ? e + j * {n_e} : ez;
      res[0] = xb; res[1] = y;
      if ({sample.name()}(arg, res, iw, ws, 0)) return 1;
      for (i = 0; i < {n_y}; ++i) if (!isfinite(y[i])) {{ reason = 2; where = i; break; }}
      if (reason) break;
      if (stop_row >= 0 && y[stop_row] != 0) {{ reason = 1; break; }}
      for (i = 0; i < {n_x}; ++i) if (!isfinite(xb[i])) {{ reason = 2; where = {n_y} + i; break; }}
      t = xa; xa = xb; xb = t;
      if (reason) {{ ++j; break; }}
    }}
    for (i = 0; i < {n_x}; ++i) xf[b * {n_x} + i] = xa[i];
    info[b * {BATCH_INFO}] = (casadi_real)j;
    info[b * {BATCH_INFO} + 1] = (casadi_real)reason;
    info[b * {BATCH_INFO} + 2] = (casadi_real)where;
  }}
  return 0;
}}
"""


def batch_work(sample: ca.Function) -> tuple[int, int]:
    """(integers, doubles) of work a :func:`batch_driver` of ``sample`` needs."""
    n_a = sample.sparsity_in(0).nnz()
    return (max(1, sample.sz_iw()),
            2 * n_a + sample.sparsity_out(1).nnz() + sample.sparsity_in(2).nnz()
            + sample.sz_w())


def render(spec: BundleSpec) -> dict[str, bytes]:
    """The bundle's files as bytes, keyed by file name (nothing is written)."""
    names = [g.function.name() for g in spec.functions]
    if len(set(names)) != len(names):
        raise ValueError(f"functions: duplicate names in bundle {spec.name!r}: {names}")
    for n in names:
        if not n.startswith(spec.name + "_"):
            raise ValueError(f"functions: {n!r} must be named {spec.name}_<quantity>")
    loops = {f.name(): f for f in (g.function for g in spec.functions)
             if f.name() in spec.loops}
    if set(loops) != set(spec.loops):
        raise ValueError(f"loops: {', '.join(sorted(set(spec.loops) - set(loops)))} "
                         f"not among the functions of bundle {spec.name!r}")
    c_src, h_src = _emit(spec)
    c_src = apply_orders(c_src, {g.function.name(): (g.function, g.order)
                                 for g in spec.functions if g.order is not None})
    for name, f in loops.items():
        c_src = _plain_loop(c_src, f, spec.loops[name])
    # Functions at their own level (chosen by the bundle from measurements, never by
    # timing at generate time: generated/ stays byte-identical everywhere).
    levels = {g.function.name(): g.optimization for g in spec.functions
              if g.optimization not in (None, spec.optimization)}
    c_src = with_levels(c_src, names, levels)
    for name, sample in spec.batches.items():
        if sample.name() not in names:
            raise ValueError(f"batches: {sample.name()} (of {name}) is not among the "
                             f"functions of bundle {spec.name!r}")
        c_src += batch_driver(name, sample).encode()
    digest = content_hash(spec.identity)
    manifest = {
        "model": spec.name,
        "hash": digest,
        "casadi_version": ca.__version__,
        "softgen_codegen_version": CODEGEN_VERSION,
        "library": library_name(spec.name, c_src, spec.optimization),
        "source_sha256": hashlib.sha256(c_src).hexdigest(),
        # The header too: an edited declaration (one double made float) would compile
        # against the library and silently corrupt every call (issue 23).
        "header_sha256": hashlib.sha256(h_src).hexdigest(),
        "parameters": spec.parameters,
        "functions": {
            g.function.name(): {**signature(g.function), "doc": g.doc,
                                "instructions": int(g.function.n_instructions()),
                                "can_fail": _can_fail(g.function),
                                **({"optimization": levels[g.function.name()]}
                                   if g.function.name() in levels else {})}
            for g in spec.functions
        },
        **spec.extra,
        # Only when not the default: model bundles' manifests stay byte-identical.
        **({"optimization": spec.optimization} if spec.optimization != "-O3" else {}),
    }
    try:   # strict JSON: a non-finite number is an error here, never "Infinity" on disk
        text = json.dumps(manifest, indent=2, sort_keys=False, allow_nan=False) + "\n"
    except ValueError:
        from softgen.codegen.manifest import validate_manifest   # names the offending key
        validate_manifest(manifest, f"{spec.name}/manifest.json (not written)")
        raise
    from softgen.codegen.manifest import validate_manifest   # what the loader will check, checked first
    validate_manifest(manifest, f"{spec.name}/manifest.json (not written)")
    return {f"{spec.name}.c": c_src, f"{spec.name}.h": h_src, "manifest.json": text.encode()}


def write_bundle(spec: BundleSpec, out_root: Path) -> Path:
    """Write ``out_root/<name>/{<name>.c, <name>.h, manifest.json}``; return the bundle dir.

    Files whose bytes are unchanged are not rewritten, so their timestamps (and any
    build system watching them) stay quiet.
    """
    bundle = Path(out_root) / spec.name
    files = render(spec)
    clean_orphans(bundle, tuple(f".{fname}." for fname in files))
    changed = {}
    for fname, data in files.items():
        path = bundle / fname
        if path.is_file() and path.read_bytes() == data:
            continue
        changed[fname] = data
    # All or nothing (issue 36): the new files are complete on disk before any replaces
    # its namesake, the manifest last; a full disk keeps the earlier bundle whole.
    if changed:
        write_set(bundle, changed, last=("manifest.json",))
    return bundle
