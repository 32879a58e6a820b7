/* main.c: the example loop of the exported @MODEL@ bundle (written by `softgen export`).
 *
 * Decoupled adaptive position and stiffness control (thesis Theorem 5, section 10.2,
 * @MODEL@_theorem5) of the McKibben arm with the pressures applied as commanded,
 * clipped to [0, p_max] (@MODEL@_pneumatic_plant: RK4 substeps over one sample,
 * pressures held), at a fixed rate of 1/EX_DT Hz. Per sample k, at t = k EX_DT:
 *
 *   ref = (q_d, qd_d, qdd_d, qddd_d, sigma_d, sigmad_d) at t (sinusoids, analytic)
 *   sigma               <- @MODEL@_mckibben_torque(q, p)    the stiffness acting now
 *   (z', p_cmd, ...)    <- @MODEL@_theorem5(z, q, qd, sigma, ref,
 *                                            lam, kd, kpi, ksigma, kinv, dt)
 *   p                   <- p_cmd clipped to [0, p_max]
 *   x = (q, qd)         <- @MODEL@_pneumatic_plant(x, p, dt)
 *
 * with z = (nu, Pi_hat). Before the loop, nu and the pressures are preset as in
 * section 10.2's "initially inflated" phase: the open-loop stiffness step
 * (@MODEL@_open_loop_stiffness, K_pi = 0) at the initial state gives the nu and p
 * that produce sigma_d(0) by the actuator model. CSV row k holds the state at t,
 * sigma and sigma_d, the controller state z at t and the command p_cmd (before
 * clipping). Gains and reference are in example_config.h. softgen.export.python_loop
 * runs the same loop with CasADi.
 */
#define _POSIX_C_SOURCE 200809L
#include "softgen_loop.h"
#include "@MODEL@_api.h"
#include "example_config.h"

typedef struct {
  @MODEL@_theorem5_t ctrl;
  @MODEL@_mckibben_torque_t stiffness;
  @MODEL@_pneumatic_plant_t plant;
  double x[2 * EX_N];        /* q, qd */
  double z[EX_N + EX_NP];    /* nu, Pi_hat */
  double p[2 * EX_N];        /* pressures acting now (clipped) */
  sg_err err[EX_N];          /* q - q_d */
  sg_err serr[EX_N];         /* sigma - sigma_d */
  long clipped;              /* pressure commands outside [0, p_max] */
} loop_t;

/* Static: the wrappers carry their work buffers. */
static loop_t L;

/* ref = (q_d, qd_d, qdd_d, qddd_d, sigma_d, sigmad_d), EX_N each. */
static void reference(double t, double *ref) {
  int i;
  for (i = 0; i < EX_N; ++i) {
    const double a = EX_REF_AMPLITUDE[i], w = EX_REF_OMEGA[i];
    const double arg = w * t + EX_REF_PHASE[i];
    const double s = sin(arg), c = cos(arg);
    const double as = EX_SIGMA_AMPLITUDE[i], ws = EX_SIGMA_OMEGA[i];
    const double args = ws * t + EX_SIGMA_PHASE[i];
    ref[i] = EX_REF_OFFSET[i] + a * s;
    ref[EX_N + i] = a * w * c;
    ref[2 * EX_N + i] = -a * w * w * s;
    ref[3 * EX_N + i] = -a * w * w * w * c;
    ref[4 * EX_N + i] = EX_SIGMA_OFFSET[i] + as * sin(args);
    ref[5 * EX_N + i] = as * ws * cos(args);
  }
}

static double clip(double v, double hi) { return fmin(fmax(v, 0.0), hi); }

static int step(void *ctx, long k, double *row, long long *ctrl_ns) {
  loop_t *l = (loop_t *)ctx;
  const double t = (double)k * EX_DT;
  const long long t0 = sg_now();
  const double *ref = l->ctrl.in.ref;
  int rc, i, c = 0;
  reference(t, l->ctrl.in.ref);
  memcpy(l->stiffness.in.q, l->x, EX_N * sizeof(double));
  memcpy(l->stiffness.in.p, l->p, sizeof l->p);
  if ((rc = @MODEL@_mckibben_torque_eval(&l->stiffness)))
    return sg_fail("@MODEL@_mckibben_torque", rc);
  memcpy(l->ctrl.in.z, l->z, sizeof l->z);
  memcpy(l->ctrl.in.q, l->x, EX_N * sizeof(double));
  memcpy(l->ctrl.in.qd, l->x + EX_N, EX_N * sizeof(double));
  memcpy(l->ctrl.in.sigma, l->stiffness.out.sigma, EX_N * sizeof(double));
  if ((rc = @MODEL@_theorem5_eval(&l->ctrl))) return sg_fail("@MODEL@_theorem5", rc);
  *ctrl_ns = sg_now() - t0;

  row[c++] = (double)k;
  row[c++] = t;
  for (i = 0; i < 2 * EX_N; ++i) row[c++] = l->x[i];
  for (i = 0; i < EX_N; ++i) row[c++] = ref[i];
  for (i = 0; i < EX_N; ++i) row[c++] = l->ctrl.in.sigma[i];
  for (i = 0; i < EX_N; ++i) row[c++] = ref[4 * EX_N + i];
  for (i = 0; i < EX_N + EX_NP; ++i) row[c++] = l->z[i];
  for (i = 0; i < 2 * EX_N; ++i) row[c++] = l->ctrl.out.p[i];
  for (i = 0; i < EX_N; ++i) {
    sg_err_add(&l->err[i], l->x[i] - ref[i]);
    sg_err_add(&l->serr[i], l->ctrl.in.sigma[i] - ref[4 * EX_N + i]);
  }

  for (i = 0; i < 2 * EX_N; ++i) {
    l->p[i] = clip(l->ctrl.out.p[i], EX_P_MAX[i]);
    l->clipped += l->p[i] != l->ctrl.out.p[i];
  }
  memcpy(l->plant.in.x, l->x, sizeof l->x);
  memcpy(l->plant.in.p, l->p, sizeof l->p);
  if ((rc = @MODEL@_pneumatic_plant_eval(&l->plant))) return sg_fail("@MODEL@_pneumatic_plant", rc);
  memcpy(l->x, l->plant.out.x_next, sizeof l->x);
  memcpy(l->z, l->ctrl.out.z_next, sizeof l->z);
  return 0;
}

/* nu and p of the open-loop stiffness step (K_pi = 0) at the initial state. */
static int preset(void) {
  static @MODEL@_open_loop_stiffness_t ol;
  int rc, i;
  if ((rc = @MODEL@_open_loop_stiffness_init(&ol))) return sg_fail("@MODEL@_open_loop_stiffness_init", rc);
  memcpy(ol.in.z, EX_PI_HAT0, sizeof EX_PI_HAT0);
  memcpy(ol.in.q, EX_X0, EX_N * sizeof(double));
  memcpy(ol.in.qd, EX_X0 + EX_N, EX_N * sizeof(double));
  reference(0.0, ol.in.ref);
  memcpy(ol.in.lam, EX_LAM, sizeof EX_LAM);
  memcpy(ol.in.kd, EX_KD, sizeof EX_KD);
  memcpy(ol.in.kinv, EX_KINV, sizeof EX_KINV);   /* kpi stays 0 (init zeroes inputs) */
  ol.in.dt[0] = EX_DT;
  if ((rc = @MODEL@_open_loop_stiffness_eval(&ol))) return sg_fail("@MODEL@_open_loop_stiffness", rc);
  memcpy(L.z, ol.out.nu, EX_N * sizeof(double));
  memcpy(L.z + EX_N, EX_PI_HAT0, sizeof EX_PI_HAT0);
  for (i = 0; i < 2 * EX_N; ++i) L.p[i] = clip(ol.out.p[i], EX_P_MAX[i]);
  @MODEL@_open_loop_stiffness_free(&ol);
  return 0;
}

int main(int argc, char **argv) {
  sg_opts o;
  sg_run r;
  int rc;
  if ((rc = sg_parse(argc, argv, EX_DEFAULT_STEPS, EX_DT, &o))) return rc == 1 ? 0 : 2;
  if (o.check) return sg_check_wrappers(@MODEL@_api_check_all, "@MODEL@");
  if ((rc = @MODEL@_theorem5_init(&L.ctrl))) return sg_fail("@MODEL@_theorem5_init", rc);
  if ((rc = @MODEL@_mckibben_torque_init(&L.stiffness)))
    return sg_fail("@MODEL@_mckibben_torque_init", rc);
  if ((rc = @MODEL@_pneumatic_plant_init(&L.plant))) return sg_fail("@MODEL@_pneumatic_plant_init", rc);
  /* Inputs that stay constant: set once (eval never writes its inputs). */
  memcpy(L.ctrl.in.lam, EX_LAM, sizeof EX_LAM);
  memcpy(L.ctrl.in.kd, EX_KD, sizeof EX_KD);
  memcpy(L.ctrl.in.kpi, EX_KPI, sizeof EX_KPI);
  memcpy(L.ctrl.in.ksigma, EX_KSIGMA, sizeof EX_KSIGMA);
  memcpy(L.ctrl.in.kinv, EX_KINV, sizeof EX_KINV);
  L.ctrl.in.dt[0] = EX_DT;
  L.plant.in.h[0] = EX_DT;
  memcpy(L.x, EX_X0, sizeof EX_X0);
  if ((rc = preset())) return 1;

  if (sg_run_example(&r, &o, EX_DT, EX_NCOL, "@MODEL@: Theorem 5 on @MODEL@_pneumatic_plant",
                     step, &L))
    return 1;
  sg_print_errors("tracking error q - q_d", "rad", L.err, EX_N, o.steps);
  sg_print_errors("stiffness error sigma - sigma_d", "N m/rad", L.serr, EX_N, o.steps);
  printf("pressure commands clipped to [0, p_max]: %ld of %ld\n", L.clipped, 2 * EX_N * o.steps);
  rc = sg_finish_example(&r, &o, EX_DT, EX_COLUMNS);
  @MODEL@_theorem5_free(&L.ctrl);
  @MODEL@_mckibben_torque_free(&L.stiffness);
  @MODEL@_pneumatic_plant_free(&L.plant);
  return rc;
}
