"""Typed C wrappers of a bundle's functions, emitted from its manifest (``softgen export``).

Per generated function ``<f>``: a struct ``<f>_t`` with the inputs in ``in`` and the
outputs in ``out`` (named as in the manifest, dense, column-major), work buffers sized
at compile time by CasADi's ``<f>_SZ_*`` macros, and ``<f>_init``, ``<f>_eval``,
``<f>_free`` built on the hand-written ``softgen_rt.h`` (whose ``softgen_rt_init``
checks the buffers against ``<f>_work()`` and the shapes against the sparsity). Nothing
is allocated: eval can run in a real-time loop.
"""
from __future__ import annotations

import re

from softgen.core.errors import BundleError
from softgen.export.example import c_comment

_C_KEYWORDS = frozenset(
    "auto break case char const continue default do double else enum extern float for goto if "
    "inline int long register restrict return short signed sizeof static struct switch "
    "typedef union unsigned void volatile while in out".split())


def _members(signals: list[dict]) -> list[tuple[str, str, int, int]]:
    """(C member name, original name, rows, cols) of a function's inputs or outputs."""
    out, seen = [], set()
    for s in signals:
        name = re.sub(r"\W", "_", s["name"]) or "x"
        if name[0].isdigit() or name in _C_KEYWORDS:
            name = f"{name}_"
        base, i = name, 2
        while name in seen:
            name, i = f"{base}_{i}", i + 1
        seen.add(name)
        out.append((name, s["name"], int(s["shape"][0]), int(s["shape"][1])))
    return out


def api_header(manifest: dict, h_src: str) -> str:
    m = manifest["model"]
    guard = f"{m.upper()}_API_H"
    lines = [f"/* {m}_api.h: typed wrappers of the functions generated for {m}.",
             " *",
             " * Written by `softgen export` from manifest.json. Per function <f>: a struct <f>_t",
             " * with the inputs in `in` and the outputs in `out` (dense, column-major), work",
             " * buffers sized by the generated <f>_SZ_* macros, and <f>_init, <f>_eval,",
             " * <f>_free (softgen_rt.h). Keep the structs static or global: they hold the",
             " * work buffers, which can be large.",
             " */",
             f"#ifndef {guard}", f"#define {guard}", "",
             f'#include "{m}.h"', '#include "softgen_rt.h"', "",
             "#ifdef __cplusplus", 'extern "C" {', "#endif", "",
             f"#define {m.upper()}_API_N_FUNCTIONS {len(manifest['functions'])}", ""]
    for f, sig in manifest["functions"].items():
        for sz in ("ARG", "RES", "IW", "W"):
            if not re.search(rf"^#define {re.escape(f)}_SZ_{sz} \d+$", h_src, re.M):
                raise BundleError(f"{m}/{m}.h: no #define {f}_SZ_{sz}; regenerate the bundle")
        lines += [f"/* {f}: {c_comment(sig.get('doc', ''))} */", "typedef struct {"]
        for part, key in (("in", "inputs"), ("out", "outputs")):
            members = _members(sig[key])
            if not members:
                lines.append(f"  struct {{ casadi_real unused_; }} {part};   /* none */")
                continue
            lines.append("  struct {")
            for name, orig, r, c in members:
                note = f"{r} x {c}" + (f", '{orig}'" if name != orig else "")
                lines.append(f"    casadi_real {name}[{max(r * c, 1)}];   /* {note} */")
            lines.append(f"  }} {part};")
        lines += [f"  const casadi_real *arg[SOFTGEN_RT_DIM({f}_SZ_ARG)];",
                  f"  casadi_real *res[SOFTGEN_RT_DIM({f}_SZ_RES)];",
                  f"  casadi_int iw[SOFTGEN_RT_DIM({f}_SZ_IW)];",
                  f"  casadi_real w[SOFTGEN_RT_DIM({f}_SZ_W)];",
                  "  int mem;     /* CasADi memory of _checkout */",
                  "  int ready;   /* 1 from a successful init to free */",
                  f"}} {f}_t;",
                  f"int {f}_init({f}_t *f);",
                  f"int {f}_eval({f}_t *f);",
                  f"void {f}_free({f}_t *f);", ""]
    lines += ["/* Initialise and release the wrapper of every function above: SOFTGEN_RT_OK, or",
              "   the first error with *failed set to the function's name. *count: how many",
              "   succeeded. */",
              f"int {m}_api_check_all(const char **failed, int *count);", "",
              "#ifdef __cplusplus", '} /* extern "C" */', "#endif", "",
              f"#endif /* {guard} */", ""]
    return "\n".join(lines)


def api_source(manifest: dict) -> str:
    m = manifest["model"]
    lines = [f"/* {m}_api.c: typed wrappers of the functions generated for {m} (see {m}_api.h).",
             " * Written by `softgen export` from manifest.json. */",
             "#include <string.h>", "", f'#include "{m}_api.h"', ""]
    check = []
    for f, sig in manifest["functions"].items():
        ins, outs = _members(sig["inputs"]), _members(sig["outputs"])
        shape = lambda ms: ", ".join(f"{r}, {c}" for _, _, r, c in ms) or "0"   # noqa: E731
        lines += [f"/* {f} */",
                  f"static const casadi_int {f}_shape_in[] = {{{shape(ins)}}};",
                  f"static const casadi_int {f}_shape_out[] = {{{shape(outs)}}};",
                  f"static const softgen_rt_desc {f}_desc = {{",
                  f'  "{f}", {len(ins)}, {len(outs)}, {f}_shape_in, {f}_shape_out,',
                  f"  {f}_n_in, {f}_n_out, {f}_work, {f}_sparsity_in, {f}_sparsity_out,",
                  f"  {f}_checkout, {f}_release, {f}_incref, {f}_decref}};", "",
                  f"int {f}_init({f}_t *f) {{",
                  "  memset(f, 0, sizeof *f);",
                  f"  return softgen_rt_init(&{f}_desc, &f->mem, &f->ready, "
                  f"SOFTGEN_RT_DIM({f}_SZ_ARG),",
                  f"                         SOFTGEN_RT_DIM({f}_SZ_RES), "
                  f"SOFTGEN_RT_DIM({f}_SZ_IW), SOFTGEN_RT_DIM({f}_SZ_W));",
                  "}", "",
                  f"int {f}_eval({f}_t *f) {{",
                  "  if (!f->ready) return SOFTGEN_RT_ENOTREADY;",
                  "  /* Set every call: the struct may have been copied since init. */"]
        lines += [f"  f->arg[{i}] = f->in.{name};" for i, (name, *_) in enumerate(ins)]
        lines += [f"  f->res[{i}] = f->out.{name};" for i, (name, *_) in enumerate(outs)]
        lines += [f"  return {f}(f->arg, f->res, f->iw, f->w, f->mem) ? SOFTGEN_RT_EEVAL "
                  ": SOFTGEN_RT_OK;", "}", "",
                  f"void {f}_free({f}_t *f) {{ softgen_rt_free(&{f}_desc, &f->mem, &f->ready); }}",
                  ""]
        check += ["  {", f"    static {f}_t s;", f"    if ((rc = {f}_init(&s))) {{",
                  f'      *failed = "{f}";', "      return rc;", "    }",
                  f"    {f}_free(&s);", "    ++*count;", "  }"]
    lines += [f"int {m}_api_check_all(const char **failed, int *count) {{", "  int rc;",
              "  *count = 0;", *check, "  return SOFTGEN_RT_OK;", "}", ""]
    return "\n".join(lines)
