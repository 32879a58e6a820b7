/* main.c: the example loop of the exported @MODEL@ bundle (written by `softgen export`).
 *
 * Slotine-Li adaptive control (thesis Prop. 10, @MODEL@_slotine_li) of the nominal arm
 * (@MODEL@_plant_rk4: one RK4 step per sample, torque held), at a fixed rate of
 * 1/EX_DT Hz. Per sample k, at t = k EX_DT:
 *
 *   (q_d, qd_d, qdd_d)  <- sinusoidal reference at t, derivatives analytic
 *   (pi_hat', tau)      <- @MODEL@_slotine_li(pi_hat, q, qd, q_d, qd_d, qdd_d,
 *                                              lam, kd, kpi, dt)
 *   x = (q, qd)         <- @MODEL@_plant_rk4(x, tau, dt)
 *
 * CSV row k holds the state at t (before the sample), the reference, the estimate
 * pi_hat at t and the torque of the sample. Gains, initial state and reference are in
 * example_config.h. softgen.export.python_loop runs the same loop with CasADi.
 */
#define _POSIX_C_SOURCE 200809L
#include "softgen_loop.h"
#include "@MODEL@_api.h"
#include "example_config.h"

typedef struct {
  @MODEL@_slotine_li_t ctrl;
  @MODEL@_plant_rk4_t plant;
  double x[2 * EX_N];       /* q, qd */
  double pi_hat[EX_NP];
  sg_err err[EX_N];         /* q - q_d */
} loop_t;

/* Static: the wrappers carry their work buffers. */
static loop_t L;

static void reference(double t, double *q_d, double *qd_d, double *qdd_d) {
  int i;
  for (i = 0; i < EX_N; ++i) {
    const double a = EX_REF_AMPLITUDE[i], w = EX_REF_OMEGA[i];
    const double arg = w * t + EX_REF_PHASE[i];
    const double s = sin(arg), c = cos(arg);
    q_d[i] = EX_REF_OFFSET[i] + a * s;
    qd_d[i] = a * w * c;
    qdd_d[i] = -a * w * w * s;
  }
}

static int step(void *ctx, long k, double *row, long long *ctrl_ns) {
  loop_t *l = (loop_t *)ctx;
  const double t = (double)k * EX_DT;
  const long long t0 = sg_now();
  int rc, i, c = 0;
  reference(t, l->ctrl.in.q_d, l->ctrl.in.qd_d, l->ctrl.in.qdd_d);
  memcpy(l->ctrl.in.pi_hat, l->pi_hat, sizeof l->pi_hat);
  memcpy(l->ctrl.in.q, l->x, EX_N * sizeof(double));
  memcpy(l->ctrl.in.qd, l->x + EX_N, EX_N * sizeof(double));
  if ((rc = @MODEL@_slotine_li_eval(&l->ctrl))) return sg_fail("@MODEL@_slotine_li", rc);
  *ctrl_ns = sg_now() - t0;

  row[c++] = (double)k;
  row[c++] = t;
  for (i = 0; i < 2 * EX_N; ++i) row[c++] = l->x[i];
  for (i = 0; i < EX_N; ++i) row[c++] = l->ctrl.in.q_d[i];
  for (i = 0; i < EX_NP; ++i) row[c++] = l->pi_hat[i];
  for (i = 0; i < EX_N; ++i) row[c++] = l->ctrl.out.tau[i];
  for (i = 0; i < EX_N; ++i) sg_err_add(&l->err[i], l->x[i] - l->ctrl.in.q_d[i]);

  memcpy(l->plant.in.x, l->x, sizeof l->x);
  memcpy(l->plant.in.tau, l->ctrl.out.tau, EX_N * sizeof(double));
  if ((rc = @MODEL@_plant_rk4_eval(&l->plant))) return sg_fail("@MODEL@_plant_rk4", rc);
  memcpy(l->x, l->plant.out.x_next, sizeof l->x);
  memcpy(l->pi_hat, l->ctrl.out.pi_hat_next, sizeof l->pi_hat);
  return 0;
}

int main(int argc, char **argv) {
  sg_opts o;
  sg_run r;
  int rc;
  if ((rc = sg_parse(argc, argv, EX_DEFAULT_STEPS, EX_DT, &o))) return rc == 1 ? 0 : 2;
  if (o.check) return sg_check_wrappers(@MODEL@_api_check_all, "@MODEL@");
  if ((rc = @MODEL@_slotine_li_init(&L.ctrl))) return sg_fail("@MODEL@_slotine_li_init", rc);
  if ((rc = @MODEL@_plant_rk4_init(&L.plant))) return sg_fail("@MODEL@_plant_rk4_init", rc);
  /* Inputs that stay constant: set once (eval never writes its inputs). */
  memcpy(L.ctrl.in.lam, EX_LAM, sizeof EX_LAM);
  memcpy(L.ctrl.in.kd, EX_KD, sizeof EX_KD);
  memcpy(L.ctrl.in.kpi, EX_KPI, sizeof EX_KPI);
  L.ctrl.in.dt[0] = EX_DT;
  L.plant.in.h[0] = EX_DT;
  memcpy(L.x, EX_X0, sizeof EX_X0);
  memcpy(L.pi_hat, EX_PI_HAT0, sizeof EX_PI_HAT0);

  if (sg_run_example(&r, &o, EX_DT, EX_NCOL, "@MODEL@: Slotine-Li (Prop. 10) on @MODEL@_plant_rk4",
                     step, &L))
    return 1;
  sg_print_errors("tracking error q - q_d", "rad", L.err, EX_N, o.steps);
  rc = sg_finish_example(&r, &o, EX_DT, EX_COLUMNS);
  @MODEL@_slotine_li_free(&L.ctrl);
  @MODEL@_plant_rk4_free(&L.plant);
  return rc;
}
