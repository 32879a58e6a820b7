/* softgen_loop.h: the fixed-rate loop, its timing statistics and the command line of the
 * example program of an exported softgen project (hand-written, the same for every model).
 *
 * The loop wakes at absolute deadlines t_0 + (k + 1) T on CLOCK_MONOTONIC
 * (clock_nanosleep with TIMER_ABSTIME), so the sampling grid does not drift with the
 * compute time, and runs one sample of the model's step function. A step that ends
 * after the next deadline is an overrun: it is counted and the loop keeps the grid (the
 * following samples start late until it catches up), as a controller that must stay
 * synchronised with its sensors would. Everything the loop touches is allocated and
 * written once before it starts; the loop itself allocates nothing and prints nothing.
 *
 * POSIX (Linux, the BSDs). The including file defines _POSIX_C_SOURCE first.
 */
#ifndef SOFTGEN_LOOP_H
#define SOFTGEN_LOOP_H

#include <errno.h>
#include <math.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#include "softgen_rt.h"

/* Command-line options of the example. */
typedef struct {
  long steps;        /* samples to run */
  int fast;          /* no sleeping: run the samples back to back */
  int rt;            /* try mlockall and SCHED_FIFO before the loop */
  int check;         /* initialise and release every wrapper of the bundle, then exit */
  const char *csv;   /* write the trajectory here (NULL: do not record it) */
} sg_opts;

static void sg_usage(FILE *out, const char *prog, long default_steps, double dt) {
  fprintf(out,
          "usage: %s [--fast] [--steps N | --seconds S] [--csv FILE] [--rt] [--check]\n"
          "  --fast        run as fast as possible (no sleeping between samples)\n"
          "  --steps N     run N samples (default %ld, i.e. %g s at %g Hz)\n"
          "  --seconds S   run S seconds of samples\n"
          "  --csv FILE    write the trajectory (one row per sample, %%.17g) to FILE\n"
          "  --rt          try mlockall and SCHED_FIFO first (reported if refused)\n"
          "  --check       initialise and release every function wrapper, then exit\n",
          prog, default_steps, default_steps * dt, 1.0 / dt);
}

/* 0: run; 1: --help was printed; 2: bad arguments (one line on stderr). */
static int sg_parse(int argc, char **argv, long default_steps, double dt, sg_opts *o) {
  int i, have_steps = 0, have_seconds = 0;
  memset(o, 0, sizeof *o);
  o->steps = default_steps;
  for (i = 1; i < argc; ++i) {
    const char *a = argv[i];
    char *end = NULL;
    if (!strcmp(a, "--fast")) {
      o->fast = 1;
    } else if (!strcmp(a, "--rt")) {
      o->rt = 1;
    } else if (!strcmp(a, "--check")) {
      o->check = 1;
    } else if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
      sg_usage(stdout, argv[0], default_steps, dt);
      return 1;
    } else if (!strcmp(a, "--steps") || !strcmp(a, "--seconds") || !strcmp(a, "--csv")) {
      if (i + 1 >= argc) {
        fprintf(stderr, "%s: error: %s needs a value\n", argv[0], a);
        return 2;
      }
      const char *v = argv[++i];
      if (!strcmp(a, "--csv")) {
        o->csv = v;
      } else if (!strcmp(a, "--steps")) {
        long n;
        errno = 0;
        n = strtol(v, &end, 10);
        if (errno || end == v || *end || n < 1) {
          fprintf(stderr, "%s: error: --steps: expected a positive integer, got '%s'\n",
                  argv[0], v);
          return 2;
        }
        o->steps = n;
        have_steps = 1;
      } else {
        double s;
        errno = 0;
        s = strtod(v, &end);
        if (errno || end == v || *end || !(s > 0) || !(s / dt < 1e15) || s / dt < 0.5) {
          fprintf(stderr, "%s: error: --seconds: expected a number of seconds >= %g, got '%s'\n",
                  argv[0], dt, v);
          return 2;
        }
        o->steps = (long)floor(s / dt + 0.5);
        have_seconds = 1;
      }
    } else {
      fprintf(stderr, "%s: error: unknown argument '%s' (try --help)\n", argv[0], a);
      return 2;
    }
  }
  if (have_steps && have_seconds) {
    fprintf(stderr, "%s: error: give --steps or --seconds, not both\n", argv[0]);
    return 2;
  }
  return 0;
}

/* Lock memory and ask for SCHED_FIFO; say what was granted (an unprivileged user usually
   gets neither, and the loop then runs as an ordinary process). */
static void sg_try_realtime(void) {
  struct sched_param sp;
  int lo = sched_get_priority_min(SCHED_FIFO), hi = sched_get_priority_max(SCHED_FIFO);
  if (mlockall(MCL_CURRENT | MCL_FUTURE) == 0)
    printf("rt: memory locked (mlockall)\n");
  else
    printf("rt: mlockall refused: %s\n", strerror(errno));
  memset(&sp, 0, sizeof sp);
  sp.sched_priority = 80 < lo ? lo : 80 > hi ? hi : 80;
  if (sched_setscheduler(0, SCHED_FIFO, &sp) == 0)
    printf("rt: SCHED_FIFO, priority %d\n", sp.sched_priority);
  else
    printf("rt: SCHED_FIFO refused: %s (needs root, CAP_SYS_NICE or an rtprio limit)\n",
           strerror(errno));
}

static long long sg_ns(const struct timespec *t) {
  return (long long)t->tv_sec * 1000000000LL + t->tv_nsec;
}

static long long sg_now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return sg_ns(&t);
}

static void sg_add_ns(struct timespec *t, long long ns) {
  long long s = t->tv_nsec + ns;
  t->tv_sec += (time_t)(s / 1000000000LL);
  t->tv_nsec = (long)(s % 1000000000LL);
}

/* Running rms and max of |v| (the tracking errors). */
typedef struct {
  double sumsq, maxabs;
  long n;
} sg_err;

static void sg_err_add(sg_err *e, double v) {
  e->sumsq += v * v;
  if (fabs(v) > e->maxabs) e->maxabs = fabs(v);
  e->n++;
}

static double sg_err_rms(const sg_err *e) { return e->n ? sqrt(e->sumsq / e->n) : 0.0; }

/* One sample: fill row (the CSV columns), return 0 or an error (already printed). */
typedef int (*sg_step_fn)(void *ctx, long k, double *row);

/* What the loop records, allocated before it starts. */
typedef struct {
  long steps;
  int ncol;
  double *rows;           /* steps x ncol, or NULL without --csv */
  double *row;            /* the row written when not recording */
  long long *wake;        /* time each sample started, ns */
  long long *latency;     /* wake-up time after the deadline, ns */
  long long *compute;     /* compute time of the sample, ns */
  double *work;           /* for the percentiles */
  long overruns;          /* samples that ended after the next deadline */
  double wall_s;
} sg_run;

static void sg_run_free(sg_run *r) {
  free(r->rows);
  free(r->row);
  free(r->wake);
  free(r->latency);
  free(r->compute);
  free(r->work);
  memset(r, 0, sizeof *r);
}

/* Allocate and touch (memset) every buffer, so that no page fault lands in the loop. */
static int sg_run_alloc(sg_run *r, long steps, int ncol, int record) {
  size_t n = (size_t)steps;
  memset(r, 0, sizeof *r);
  r->steps = steps;
  r->ncol = ncol;
  r->rows = record ? malloc(n * (size_t)ncol * sizeof(double)) : NULL;
  r->row = malloc((size_t)ncol * sizeof(double));
  r->wake = malloc(n * sizeof(long long));
  r->latency = malloc(n * sizeof(long long));
  r->compute = malloc(n * sizeof(long long));
  r->work = malloc(n * sizeof(double));
  if ((record && !r->rows) || !r->row || !r->wake || !r->latency || !r->compute || !r->work) {
    sg_run_free(r);
    return 1;
  }
  if (record) memset(r->rows, 0, n * (size_t)ncol * sizeof(double));
  memset(r->row, 0, (size_t)ncol * sizeof(double));
  memset(r->wake, 0, n * sizeof(long long));
  memset(r->latency, 0, n * sizeof(long long));
  memset(r->compute, 0, n * sizeof(long long));
  memset(r->work, 0, n * sizeof(double));
  return 0;
}

/* Run r->steps samples of step at period dt (or back to back with --fast). */
static int sg_run_loop(sg_run *r, const sg_opts *o, double dt, sg_step_fn step, void *ctx) {
  const long long period = (long long)llround(dt * 1e9);
  struct timespec next;
  long long start;
  long k;
  int rc;
  clock_gettime(CLOCK_MONOTONIC, &next);
  start = sg_ns(&next);
  for (k = 0; k < r->steps; ++k) {
    long long wake, done;
    double *row = r->rows ? r->rows + (size_t)k * (size_t)r->ncol : r->row;
    if (!o->fast) {
      sg_add_ns(&next, period);   /* absolute deadline: the grid never drifts */
      while ((rc = clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL)) == EINTR) {
      }
      if (rc) {
        fprintf(stderr, "error: clock_nanosleep: %s\n", strerror(rc));
        return 1;
      }
    }
    wake = sg_now();
    rc = step(ctx, k, row);
    done = sg_now();
    if (rc) return rc;
    r->wake[k] = wake;
    r->compute[k] = done - wake;
    if (!o->fast) {
      const long long deadline = sg_ns(&next);
      r->latency[k] = wake - deadline;
      if (done > deadline + period) r->overruns++;
    }
  }
  r->wall_s = (double)(sg_now() - start) * 1e-9;
  return 0;
}

static int sg_cmp_double(const void *a, const void *b) {
  const double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

typedef struct {
  double mean, std, p99, max;
} sg_stats;

/* Mean, standard deviation, 99th percentile (nearest rank) and maximum of x[0..n). */
static sg_stats sg_summarize(const double *x, long n, double *work) {
  sg_stats s = {0.0, 0.0, 0.0, 0.0};
  long i;
  if (n <= 0) return s;
  for (i = 0; i < n; ++i) s.mean += x[i];
  s.mean /= (double)n;
  for (i = 0; i < n; ++i) s.std += (x[i] - s.mean) * (x[i] - s.mean);
  s.std = sqrt(s.std / (double)n);
  memcpy(work, x, (size_t)n * sizeof(double));
  qsort(work, (size_t)n, sizeof(double), sg_cmp_double);
  s.p99 = work[(long)ceil(0.99 * (double)n) - 1];
  s.max = work[n - 1];
  return s;
}

/* Print compute time per step and, unless --fast, the period jitter and overruns. */
static void sg_report_timing(const sg_run *r, const sg_opts *o, double dt) {
  const long n = r->steps;
  const double T = dt * 1e6;   /* us */
  double *v = malloc((size_t)(n > 1 ? n : 1) * sizeof(double));
  sg_stats s;
  long k;
  if (!v) {
    fprintf(stderr, "error: out of memory for the statistics\n");
    return;
  }
  for (k = 0; k < n; ++k) v[k] = (double)r->compute[k] * 1e-3;
  s = sg_summarize(v, n, r->work);
  printf("compute per step [us]: mean %.3f, std %.3f, p99 %.3f, max %.3f\n",
         s.mean, s.std, s.p99, s.max);
  if (o->fast) {
    printf("fast: %ld steps in %.6f s, %.0f steps/s (no sleeping, no period statistics)\n",
           n, r->wall_s, (double)n / r->wall_s);
  } else if (n > 1) {
    double mean = 0.0;
    for (k = 1; k < n; ++k) v[k - 1] = (double)(r->wake[k] - r->wake[k - 1]) * 1e-3;
    s = sg_summarize(v, n - 1, r->work);
    mean = s.mean;
    printf("period [us]: mean %.3f, std %.3f (%ld periods, target %.3f)\n", s.mean, s.std,
           n - 1, T);
    for (k = 0; k < n - 1; ++k) v[k] = fabs(v[k] - T);
    s = sg_summarize(v, n - 1, r->work);
    printf("jitter |period - %.0f us| [us]: p99 %.3f, max %.3f\n", T, s.p99, s.max);
    for (k = 0; k < n; ++k) v[k] = (double)r->latency[k] * 1e-3;
    s = sg_summarize(v, n, r->work);
    printf("wake-up latency after the deadline [us]: mean %.3f, p99 %.3f, max %.3f\n",
           s.mean, s.p99, s.max);
    printf("overruns (step ended after the next deadline): %ld of %ld\n", r->overruns, n);
    printf("rate: %.3f Hz over %.3f s\n", 1e6 / mean, r->wall_s);
  }
  free(v);
}

/* The recorded trajectory as CSV: a header of column names, then one row per sample. */
static int sg_write_csv(const char *path, const char *const *names, const sg_run *r) {
  FILE *f = fopen(path, "w");
  long k;
  int j;
  if (!f) {
    fprintf(stderr, "error: --csv %s: %s\n", path, strerror(errno));
    return 1;
  }
  for (j = 0; j < r->ncol; ++j) fprintf(f, "%s%s", j ? "," : "", names[j]);
  fputc('\n', f);
  for (k = 0; k < r->steps; ++k) {
    const double *row = r->rows + (size_t)k * (size_t)r->ncol;
    for (j = 0; j < r->ncol; ++j) fprintf(f, "%s%.17g", j ? "," : "", row[j]);
    fputc('\n', f);
  }
  if (fclose(f) != 0) {
    fprintf(stderr, "error: --csv %s: %s\n", path, strerror(errno));
    return 1;
  }
  return 0;
}

/* One line for a failed call of a wrapper, with the runtime's message; returns rc. */
static int sg_fail(const char *what, int rc) {
  fprintf(stderr, "error: %s: %s\n", what, softgen_rt_strerror(rc));
  return rc;
}

/* --check: every function wrapper of the bundle initialises (buffers and shapes agree)
 * and releases; check_all is the bundle's <model>_api_check_all. */
static int sg_check_wrappers(int (*check_all)(const char **name, int *n), const char *model) {
  const char *name = "";
  int n = 0, rc = check_all(&name, &n);
  if (rc) {
    sg_fail(name, rc);
    return 1;
  }
  printf("check: all %d function wrappers of %s initialised and released\n", n, model);
  return 0;
}

/* Per-component rms and max of an error over the run. */
static void sg_print_errors(const char *what, const char *unit, const sg_err *e, int n,
                            long steps) {
  int i;
  printf("%s over %ld samples [%s]:\n", what, steps, unit);
  for (i = 0; i < n; ++i)
    printf("  [%d]: rms %.6e, max %.6e\n", i + 1, sg_err_rms(&e[i]), e[i].maxabs);
}

/* Allocate the run's buffers (before the loop: it allocates nothing), say what runs, run
 * the loop. 0, or 1 after a message. */
static int sg_run_example(sg_run *r, const sg_opts *o, double dt, int ncol, const char *title,
                          sg_step_fn step, void *ctx) {
  if (o->rt) sg_try_realtime();
  if (sg_run_alloc(r, o->steps, ncol, o->csv != NULL)) {
    fprintf(stderr, "error: out of memory for %ld steps\n", o->steps);
    return 1;
  }
  printf("%s, %ld steps at %g Hz, %s\n", title, o->steps, 1.0 / dt,
         o->fast ? "fast (no sleeping)" : "real time");
  if (sg_run_loop(r, o, dt, step, ctx)) {
    sg_run_free(r);
    return 1;
  }
  return 0;
}

/* Timing report, the trajectory CSV if asked, buffers released. 0 or 1. */
static int sg_finish_example(sg_run *r, const sg_opts *o, double dt,
                             const char *const *columns) {
  int rc;
  sg_report_timing(r, o, dt);
  rc = o->csv ? sg_write_csv(o->csv, columns, r) : 0;
  if (!rc && o->csv) printf("trajectory: %s (%ld rows)\n", o->csv, o->steps);
  sg_run_free(r);
  return rc;
}

#endif /* SOFTGEN_LOOP_H */
