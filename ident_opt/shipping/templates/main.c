/* Minimal example: predict the joint torques of the identified arm ($n joints) from C, without Python.
 *
 * Build (from the folder that `ident-opt codegen` wrote), against the shared library:
 *   cc -O2 -std=c99 -Wall -Wextra -Werror main.c -L. -lident_opt_model -Wl,-rpath,. -o example -lm
 * or with the generated source compiled in (its CasADi signatures have unused parameters):
 *   cc -O2 -std=c99 -Wall -Wextra -Werror -Wno-unused-parameter main.c ident_opt_model.c -o example -lm
 *
 * Every buffer is static: no dynamic allocation anywhere. The CasADi calling convention is
 * f(arg, res, iw, w, mem): arg[i] points to input i, res[i] to output i, iw/w are work arrays whose sizes
 * the header gives as <f>_SZ_IW / <f>_SZ_W (also at run time via <f>_work), mem is from <f>_checkout.
 */
#include <math.h>
#include <stdio.h>

#include "ident_opt_model.h"

#define N_JOINTS $n

/* One evaluation of a (q, dq, ddq) -> tau entry point; the sizes come from the generated header. */
#define EVALUATE(f, q, dq, ddq, tau, status)                                  \
  do {                                                                        \
    const casadi_real *arg_[f##_SZ_ARG + 1];                                  \
    casadi_real *res_[f##_SZ_RES + 1];                                        \
    casadi_int iw_[f##_SZ_IW + 1]; /* +1: a zero-sized array is not C99 */    \
    casadi_real w_[f##_SZ_W + 1];                                             \
    int mem_;                                                                 \
    arg_[0] = (q);                                                            \
    arg_[1] = (dq);                                                           \
    arg_[2] = (ddq);                                                          \
    res_[0] = (tau);                                                          \
    f##_incref();                                                             \
    mem_ = f##_checkout();                                                    \
    (status) = f(arg_, res_, iw_, w_, mem_);                                  \
    f##_release(mem_);                                                        \
    f##_decref();                                                             \
  } while (0)

/* Print one torque vector and say whether every entry is finite. */
static int report(const char *name, const casadi_real *tau) {
  int finite = 1;
  printf("%-11s = [", name);
  for (int j = 0; j < N_JOINTS; ++j) {
    printf(j ? ", %.17g" : "%.17g", tau[j]);
    finite = finite && isfinite(tau[j]);
  }
  printf("] N m\n");
  return finite;
}

int main(void) {
  /* A state: joint angles [rad], velocities [rad/s], accelerations [rad/s^2]. */
  const casadi_real q[N_JOINTS] = {$q};
  const casadi_real dq[N_JOINTS] = {$dq};
  const casadi_real ddq[N_JOINTS] = {$ddq};
  casadi_real tau[N_JOINTS] = {0.0};
  int status = 0;
  int finite = 1;

  EVALUATE(tau_hat, q, dq, ddq, tau, status);
  if (status != 0) {
    fprintf(stderr, "tau_hat failed (%d)\n", status);
    return 1;
  }
  finite = report("tau_hat", tau) && finite;
$gmr_call
  return finite ? 0 : 1;
}
