/* Hand-written Slotine-Li regressor of models/planar_2link.toml (reference for
 * `softgen bench`). Same columns and layout as the generated planar_2link_regressor
 * (base parameters I1, I2, m1*c1, m2*c2, l1*m2*c2; Y 2x5, column-major), with the
 * same calling convention as CasADi-generated code so that one harness times both. */
#ifndef HAND_PLANAR_2LINK_H
#define HAND_PLANAR_2LINK_H
#ifndef casadi_real
#define casadi_real double
#endif
#ifndef casadi_int
#define casadi_int long long int
#endif
int hand_planar_2link_regressor(const casadi_real** arg, casadi_real** res, casadi_int* iw,
                                casadi_real* w, int mem);
int hand_planar_2link_regressor_checkout(void);
void hand_planar_2link_regressor_release(int mem);
void hand_planar_2link_regressor_incref(void);
void hand_planar_2link_regressor_decref(void);
casadi_int hand_planar_2link_regressor_n_in(void);
casadi_int hand_planar_2link_regressor_n_out(void);
const casadi_int* hand_planar_2link_regressor_sparsity_in(casadi_int i);
const casadi_int* hand_planar_2link_regressor_sparsity_out(casadi_int i);
int hand_planar_2link_regressor_work(casadi_int *sz_arg, casadi_int* sz_res, casadi_int *sz_iw,
                                     casadi_int *sz_w);
#endif
