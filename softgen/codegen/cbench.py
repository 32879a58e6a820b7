"""Per-call latency of generated C functions, timed in a plain C loop.

Timing through Python (ctypes or ``casadi.Function`` calls) measures the
binding overhead, which is larger than the whole evaluation of small
functions. Here a throw-away C harness calls each function in a tight loop and
reports the median nanoseconds per call, so the number is what a C controller
would pay.

Every loop is timed on the thread's CPU clock (``CLOCK_THREAD_CPUTIME_ID``), as the
peers' harness is (:mod:`softgen.app.peers`): on a machine shared with other jobs a
wall clock also counts the time the harness waited for a CPU (issue 34: the bench's
figures moved with the load). The compiler flags are the caller's choice
(``flags``) and are returned with the figures' source, so a table can name them.
"""
from __future__ import annotations

import math
import subprocess
import tempfile
from pathlib import Path

from softgen.core.errors import BuildError
from softgen.codegen.build import require_compiler

__all__ = ["time_in_c", "HARNESS_FLAGS"]

#: Flags of a harness that compiles the C source itself (no ``library``): the bundle's
#: own (:data:`softgen.codegen.build.CFLAGS` without ``-fPIC -shared``), so that a
#: function is timed as ``softgen generate`` builds it unless the caller asks otherwise.
HARNESS_FLAGS = ("-O3", "-fno-math-errno", "-fno-semantic-interposition")


_HEAD = r"""/* Benchmark harness written by softgen.codegen.cbench; safe to delete. */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
{includes}

static unsigned long long lcg_state;

/* Deterministic inputs in [-1, 1]: the same seed gives the same numbers everywhere. */
static double lcg_uniform(void) {{
  lcg_state = lcg_state * 6364136223846793005ULL + 1442695040888963407ULL;
  return (double)(lcg_state >> 11) * (2.0 / 9007199254740992.0) - 1.0;
}}

static void *xmalloc(size_t n) {{
  void *p = malloc(n ? n : 1);
  if (!p) {{ fprintf(stderr, "out of memory\n"); exit(1); }}
  return p;
}}

/* The thread's CPU clock: time the machine gave this loop, not the wall clock. */
static double now_ns(void) {{
  struct timespec t;
  if (clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t) != 0) {{
    fprintf(stderr, "clock_gettime failed\n"); exit(1);
  }}
  return (double)t.tv_sec * 1e9 + (double)t.tv_nsec;
}}

static int cmp_double(const void *a, const void *b) {{
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}}

static double median(double *v, int n) {{
  qsort(v, (size_t)n, sizeof(double), cmp_double);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}}

static casadi_int nnz_of(const casadi_int *sp) {{
  /* CasADi compressed column: [nrow, ncol, colind[ncol+1], row[nnz]], except that
     generated code writes a dense pattern as [nrow, ncol, 1] (colind[0] is 0 otherwise). */
  if (sp[2] == 1) return sp[0] * sp[1];
  return sp[2 + sp[1]];
}}

/* The sink keeps the compiler from discarding the loop or the result. */
static volatile double sink;

#define CALLS {calls}LL
#define REPEATS {repeats}
#define SEED {seed}ULL
"""

_BENCH = r"""
static struct {{
  const casadi_real **arg;
  casadi_real **res, *w;
  casadi_int *iw, n_in, n_out;
  int mem, out_k;
  double t[REPEATS];
}} b_{name};

static void setup_{name}(void) {{
  casadi_int sz_arg, sz_res, sz_iw, sz_w, i, k;
  long long c;
  b_{name}.out_k = -1;
  {name}_incref();
  if ({name}_work(&sz_arg, &sz_res, &sz_iw, &sz_w) != 0) {{
    fprintf(stderr, "{name}_work failed\n"); exit(1);
  }}
  b_{name}.n_in = {name}_n_in();
  b_{name}.n_out = {name}_n_out();
  /* arg/res are sz_arg/sz_res long: CasADi may use the tail as scratch. */
  b_{name}.arg = xmalloc(sizeof(*b_{name}.arg) * (size_t)(sz_arg > b_{name}.n_in ? sz_arg : b_{name}.n_in));
  b_{name}.res = xmalloc(sizeof(*b_{name}.res) * (size_t)(sz_res > b_{name}.n_out ? sz_res : b_{name}.n_out));
  b_{name}.iw = xmalloc(sizeof(*b_{name}.iw) * (size_t)sz_iw);
  b_{name}.w = xmalloc(sizeof(*b_{name}.w) * (size_t)sz_w);
  for (k = 0; k < sz_arg; ++k) b_{name}.arg[k] = 0;
  for (k = 0; k < sz_res; ++k) b_{name}.res[k] = 0;
  lcg_state = SEED;
  for (k = 0; k < b_{name}.n_in; ++k) {{
    casadi_int nnz = nnz_of({name}_sparsity_in(k));
    casadi_real *a = xmalloc(sizeof(casadi_real) * (size_t)nnz);
    for (i = 0; i < nnz; ++i) a[i] = lcg_uniform();
    b_{name}.arg[k] = a;
  }}
  for (k = 0; k < b_{name}.n_out; ++k) {{
    casadi_int nnz = nnz_of({name}_sparsity_out(k));
    b_{name}.res[k] = xmalloc(sizeof(casadi_real) * (size_t)nnz);
    if (b_{name}.out_k < 0 && nnz > 0) b_{name}.out_k = (int)k;
  }}
  b_{name}.mem = {name}_checkout();
  if (b_{name}.mem < 0) {{ fprintf(stderr, "{name}_checkout failed\n"); exit(1); }}
  /* Warm-up: caches, branch predictors and CPU frequency settle before timing. */
  for (c = 0; c < CALLS / 10 + 1; ++c) {{
    if ({name}(b_{name}.arg, b_{name}.res, b_{name}.iw, b_{name}.w, b_{name}.mem) != 0) {{
      fprintf(stderr, "{name} returned non-zero\n"); exit(1);
    }}
  }}
}}

static void repeat_{name}(int r) {{
  int bad = 0, out_k = b_{name}.out_k;
  long long c;
  double acc = 0.0, t0 = now_ns();
  for (c = 0; c < CALLS; ++c) {{
    bad |= {name}(b_{name}.arg, b_{name}.res, b_{name}.iw, b_{name}.w, b_{name}.mem);
    if (out_k >= 0) acc += b_{name}.res[out_k][0];
  }}
  b_{name}.t[r] = (now_ns() - t0) / (double)CALLS;
  if (bad) {{ fprintf(stderr, "{name} returned non-zero\n"); exit(1); }}
  sink += acc;
}}

static void finish_{name}(void) {{
  casadi_int k;
  printf("{name} %.6f\n", median(b_{name}.t, REPEATS));
  {name}_release(b_{name}.mem);
  {name}_decref();
  for (k = 0; k < b_{name}.n_in; ++k) free((void *)b_{name}.arg[k]);
  for (k = 0; k < b_{name}.n_out; ++k) free(b_{name}.res[k]);
  free(b_{name}.arg); free(b_{name}.res); free(b_{name}.iw); free(b_{name}.w);
}}
"""


def _c_string(text: str) -> str:
    """``text`` escaped for a C string literal (paths may hold quotes or backslashes)."""
    return text.replace("\\", "\\\\").replace('"', '\\"')


def _harness(headers: list[Path], names: list[str], calls: int, repeats: int,
             seed: int) -> str:
    includes = "\n".join(f'#include "{_c_string(str(h))}"' for h in headers)
    parts = [_HEAD.format(includes=includes, calls=calls, repeats=repeats, seed=seed % 2**64)]
    parts += [_BENCH.format(name=n) for n in names]
    parts.append("\nint main(void) {\n  int r;\n")
    parts += [f"  setup_{n}();\n" for n in names]
    # Repeats interleave the functions, so a slow spell of the machine hits all alike.
    parts.append("  for (r = 0; r < REPEATS; ++r) {\n")
    parts += [f"    repeat_{n}(r);\n" for n in names]
    parts.append("  }\n")
    parts += [f"  finish_{n}();\n" for n in names]
    parts.append("  return 0;\n}\n")
    return "".join(parts)


def time_in_c(c_file: Path, names: list[str], *, calls: int = 200_000, repeats: int = 5,
              cc: str | None = None, seed: int = 0, opt: str | None = None,
              extra_sources: list[Path] = (), library: Path | None = None,
              flags: tuple[str, ...] | list[str] | None = None) -> dict[str, float]:
    """Median nanoseconds per call of each named function, timed in a plain C loop.

    Parameters
    ----------
    c_file
        C source from ``casadi.CodeGenerator`` with ``{"with_header": True}``;
        its header (same stem, ``.h``) must sit beside it.
    names
        Functions of ``c_file`` to time (CasADi calling convention).
    calls, repeats
        Calls per timed repeat, and number of repeats (the median is reported).
    cc
        Compiler; default ``$CC``, else the first of cc, gcc, clang on PATH.
    seed
        Seed of the pseudo-random inputs in [-1, 1].
    opt
        Optimisation level of the harness (default ``-O3``); kept for callers that
        only choose the level. ``flags`` replaces it.
    flags
        Every compiler flag of the harness and, without ``library``, of ``c_file``
        (default :data:`HARNESS_FLAGS`, the bundle's own); e.g. ``("-O3",
        "-march=native")``. Each must start with ``-``.
    extra_sources
        More C files (each with its header beside it, same calling convention) compiled
        into the same harness, e.g. a hand-written reference; their functions may be
        named in ``names``. Repeats are interleaved across all functions.
    library
        A shared library already compiled from ``c_file``: the harness links to it
        instead of compiling ``c_file`` again (so a study compiles each function once).

    Returns
    -------
    dict
        ``{name: ns_per_call}``.

    Raises
    ------
    BuildError
        No compiler, the harness did not compile, or it exited with an error.
    ValueError
        A name is not a C identifier, or ``calls``/``repeats`` is not positive.
    """
    c_file = Path(c_file).resolve()
    header = c_file.with_suffix(".h")
    extra = [Path(x).resolve() for x in extra_sources]
    names = list(dict.fromkeys(names))   # a repeated name would define bench_NAME twice
    for n in names:
        # Names are pasted into C source: anything but an identifier would be injection.
        if not (n.isidentifier() and n.isascii()):
            raise ValueError(f"names: {n!r} is not a C identifier")
    if calls < 1 or repeats < 1:
        raise ValueError(f"calls and repeats must be positive, got {calls} and {repeats}")
    if flags is None:
        flags = (opt,) if opt is not None else HARNESS_FLAGS
    flags = tuple(flags)
    for f in flags:
        # Flags reach the compiler's argv (no shell); an input file or an output name
        # among them would change what is timed.
        if not (isinstance(f, str) and f.startswith("-") and f not in ("-o", "-c")):
            raise ValueError(f"flags: expected compiler options starting with '-', got {f!r}")
    if not c_file.is_file():
        raise FileNotFoundError(f"{c_file}: no such C file")
    if not header.is_file():
        raise FileNotFoundError(f"{header}: missing; generate with {{'with_header': True}}")
    for x in extra:
        if not x.is_file() or not x.with_suffix(".h").is_file():
            raise FileNotFoundError(f"extra_sources: {x} or its header is missing")
    compiler = require_compiler(cc)
    with tempfile.TemporaryDirectory(prefix="softgen-cbench-") as tmp:
        harness = Path(tmp) / "harness.c"
        exe = Path(tmp) / "harness"
        harness.write_text(_harness([header] + [x.with_suffix(".h") for x in extra], names,
                                    calls, repeats, seed))
        try:
            code = ([str(Path(library).resolve()),
                     f"-Wl,-rpath,{Path(library).resolve().parent}"] if library is not None
                    else [str(c_file)])
            subprocess.run([compiler, *flags, "-o", str(exe), str(harness), *code,
                            *map(str, extra), "-lm"],
                           check=True, capture_output=True, text=True)
        except subprocess.CalledProcessError as exc:
            raise BuildError("compiling the benchmark harness failed", exc.stderr) from None
        except OSError as exc:
            raise BuildError(f"cannot run the C compiler {compiler!r} ({exc})") from None
        proc = subprocess.run([str(exe)], capture_output=True, text=True)
        if proc.returncode != 0:
            raise BuildError(f"the benchmark harness exited with status {proc.returncode}",
                             proc.stderr)
    out: dict[str, float] = {}
    for line in proc.stdout.splitlines():
        name, _, value = line.partition(" ")
        out[name] = float(value)
    missing = [n for n in names if n not in out or not math.isfinite(out[n])]
    if missing:
        raise BuildError(f"the benchmark harness gave no timing for {', '.join(missing)}",
                         proc.stdout)
    return {n: out[n] for n in names}
