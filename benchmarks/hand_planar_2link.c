/* Hand-written planar_2link regressor; see hand_planar_2link.h.
 *
 * Angles from the downward vertical, g = 9.81 (models/planar_2link.toml). Row i,
 * column j is dtau_i/dpi_j of tau = B qdd_r + C qd_r + G with C of Christoffel
 * symbols (thesis eq. 10.9 in the Slotine-Li form of NOTES section 2 item 13):
 *   Y = [[qdd_r1, qdd_r1+qdd_r2, g s1, g s12, (2 qdd_r1 + qdd_r2) c2 - s2 (qd2 qd_r1 + (qd1+qd2) qd_r2)],
 *        [0,      qdd_r1+qdd_r2, 0,    g s12, qdd_r1 c2 + s2 qd1 qd_r1]]
 * sin q1, and sin q2 with cos q2 (one sincos), are evaluated once; sin(q1 + q2) once. */
#define _GNU_SOURCE
#include <math.h>
#include "hand_planar_2link.h"

static const casadi_int sp_in[3] = {2, 1, 1};     /* dense 2x1 */
static const casadi_int sp_out[3] = {2, 5, 1};    /* dense 2x5 */

int hand_planar_2link_regressor(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                                casadi_real* w, int mem) {
  const casadi_real *q = arg[0], *qd = arg[1], *qdr = arg[2], *qddr = arg[3];
  casadi_real *Y = res[0];
  const casadi_real g = 9.81;
  casadi_real s2, c2, s1 = sin(q[0]), s12 = sin(q[0] + q[1]);
  casadi_real a = qddr[0] + qddr[1];
  (void)iw; (void)w; (void)mem;
  sincos(q[1], &s2, &c2);
  Y[0] = qddr[0];
  Y[1] = 0.0;
  Y[2] = a;
  Y[3] = a;
  Y[4] = g * s1;
  Y[5] = 0.0;
  Y[6] = g * s12;
  Y[7] = Y[6];
  Y[8] = (qddr[0] + a) * c2 - s2 * (qd[1] * qdr[0] + (qd[0] + qd[1]) * qdr[1]);
  Y[9] = qddr[0] * c2 + s2 * qd[0] * qdr[0];
  return 0;
}

int hand_planar_2link_regressor_checkout(void) { return 0; }
void hand_planar_2link_regressor_release(int mem) { (void)mem; }
void hand_planar_2link_regressor_incref(void) {}
void hand_planar_2link_regressor_decref(void) {}
casadi_int hand_planar_2link_regressor_n_in(void) { return 4; }
casadi_int hand_planar_2link_regressor_n_out(void) { return 1; }
const casadi_int* hand_planar_2link_regressor_sparsity_in(casadi_int i) {
  return i >= 0 && i < 4 ? sp_in : 0;
}
const casadi_int* hand_planar_2link_regressor_sparsity_out(casadi_int i) {
  return i == 0 ? sp_out : 0;
}
int hand_planar_2link_regressor_work(casadi_int *sz_arg, casadi_int* sz_res, casadi_int *sz_iw,
                                     casadi_int *sz_w) {
  if (sz_arg) *sz_arg = 4;
  if (sz_res) *sz_res = 1;
  if (sz_iw) *sz_iw = 0;
  if (sz_w) *sz_w = 0;
  return 0;
}
