/* softgen_rt.h: the runtime shared by the typed wrappers of an exported softgen bundle.
 *
 * Hand-written (shipped by `softgen export`, identical for every model). Each generated
 * function <f> of the bundle gets a typed struct <f>_t (see <model>_api.h) holding its
 * named input and output arrays and its work buffers, with
 *
 *     int  <f>_init(<f>_t *f);   checks the buffers and shapes, takes a CasADi memory
 *     int  <f>_eval(<f>_t *f);   reads f->in, writes f->out; no allocation, no I/O
 *     void <f>_free(<f>_t *f);   releases the memory taken by init
 *
 * The work buffers are arrays inside the struct, sized at compile time by the
 * <f>_SZ_ARG/_SZ_RES/_SZ_IW/_SZ_W macros of the generated header; init checks them
 * against what <f>_work() asks for at run time. Nothing is ever allocated with malloc,
 * so eval can run in a real-time loop. Arrays are dense and column-major (CasADi's
 * layout): element (i, j) of an r x c input is in[i + r * j].
 *
 * Every function returns SOFTGEN_RT_OK (0) or one of the codes below; softgen_rt_strerror
 * turns a code into one line of text.
 */
#ifndef SOFTGEN_RT_H
#define SOFTGEN_RT_H

#include <stddef.h>

#ifndef casadi_real
#define casadi_real double
#endif
#ifndef casadi_int
#define casadi_int long long int
#endif

#define SOFTGEN_RT_OK 0
/* <f>_work() asks for more arg/res/iw/w entries than the struct holds (header and
   source of the generated code do not match). */
#define SOFTGEN_RT_EWORK 1
/* An input or output is not a dense matrix of the shape the wrapper was emitted for. */
#define SOFTGEN_RT_ESHAPE 2
/* <f>_checkout() gave no memory. */
#define SOFTGEN_RT_ECHECKOUT 3
/* The generated function returned non-zero (only functions built from maps or calls can). */
#define SOFTGEN_RT_EEVAL 4
/* eval or free on a struct that init did not set up (or that free already released). */
#define SOFTGEN_RT_ENOTREADY 5

/* An array length that C99 accepts: zero-sized buffers become one element. */
#define SOFTGEN_RT_DIM(n) ((n) > 0 ? (n) : 1)

static inline const char *softgen_rt_strerror(int code) {
  switch (code) {
    case SOFTGEN_RT_OK: return "ok";
    case SOFTGEN_RT_EWORK: return "work buffers too small for the generated function";
    case SOFTGEN_RT_ESHAPE: return "an input or output is not dense of the expected shape";
    case SOFTGEN_RT_ECHECKOUT: return "the generated function gave no memory (checkout)";
    case SOFTGEN_RT_EEVAL: return "the generated function returned an error";
    case SOFTGEN_RT_ENOTREADY: return "wrapper used before init (or after free)";
    default: return "unknown softgen_rt error code";
  }
}

/* What the typed wrappers need to know of one generated function. */
typedef struct {
  const char *name;
  casadi_int n_in, n_out;
  const casadi_int *shape_in;    /* rows, cols of each input */
  const casadi_int *shape_out;   /* rows, cols of each output */
  casadi_int (*f_n_in)(void);
  casadi_int (*f_n_out)(void);
  int (*work)(casadi_int *sz_arg, casadi_int *sz_res, casadi_int *sz_iw, casadi_int *sz_w);
  const casadi_int *(*sparsity_in)(casadi_int i);
  const casadi_int *(*sparsity_out)(casadi_int i);
  int (*checkout)(void);
  void (*release)(int mem);
  void (*incref)(void);
  void (*decref)(void);
} softgen_rt_desc;

/* Whether CasADi sparsity pattern sp is a dense rows x cols matrix. The pattern is
   {nrow, ncol, colind[ncol + 1], row[nnz]}, or {nrow, ncol, 1} for a dense one (the
   compact form: a real colind starts with 0). */
static inline int softgen_rt_dense(const casadi_int *sp, casadi_int rows, casadi_int cols) {
  if (!sp || sp[0] != rows || sp[1] != cols) return 0;
  if (sp[2] == 1) return 1;
  return sp[2 + cols] == rows * cols;
}

/* The checks and the memory of <f>_init. The capacities are the lengths of the struct's
   arg, res, iw and w arrays. */
static inline int softgen_rt_init(const softgen_rt_desc *d, int *mem, int *ready,
                                  casadi_int cap_arg, casadi_int cap_res, casadi_int cap_iw,
                                  casadi_int cap_w) {
  casadi_int sz_arg = 0, sz_res = 0, sz_iw = 0, sz_w = 0, i;
  int m;
  *ready = 0;
  d->incref();
  if (d->f_n_in() != d->n_in || d->f_n_out() != d->n_out) goto shape;
  if (d->work(&sz_arg, &sz_res, &sz_iw, &sz_w) != 0 || sz_arg > cap_arg || sz_res > cap_res
      || sz_iw > cap_iw || sz_w > cap_w) {
    d->decref();
    return SOFTGEN_RT_EWORK;
  }
  for (i = 0; i < d->n_in; ++i)
    if (!softgen_rt_dense(d->sparsity_in(i), d->shape_in[2 * i], d->shape_in[2 * i + 1]))
      goto shape;
  for (i = 0; i < d->n_out; ++i)
    if (!softgen_rt_dense(d->sparsity_out(i), d->shape_out[2 * i], d->shape_out[2 * i + 1]))
      goto shape;
  m = d->checkout();
  if (m < 0) {
    d->decref();
    return SOFTGEN_RT_ECHECKOUT;
  }
  *mem = m;
  *ready = 1;
  return SOFTGEN_RT_OK;
shape:
  d->decref();
  return SOFTGEN_RT_ESHAPE;
}

/* The release of <f>_free; a second free is harmless. */
static inline void softgen_rt_free(const softgen_rt_desc *d, int *mem, int *ready) {
  if (!*ready) return;
  d->release(*mem);
  d->decref();
  *ready = 0;
}

#endif /* SOFTGEN_RT_H */
