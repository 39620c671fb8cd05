/* Timing loop for the generated torque predictors: nanoseconds per call of tau_hat, tau_hat_gmr, ddq_hat.
 *
 * Built by benchmarks/bench_codegen.py together with the generated source, as firmware would be:
 *   cc -O2 -std=c99 -Wall -Wextra -Werror -I<generated dir> bench_codegen.c <dir>/ident_opt_model.c -lm
 * Each function is called through a pointer (no inlining into the loop) on 1024 distinct states, cycled, so
 * the compiler cannot hoist the work; every output feeds a checksum that is printed. Each function is timed
 * REPEATS times and the fastest repetition is reported (the least disturbed by other processes).
 * Output, one line per function: "<name> <ns per call> <checksum>".
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "ident_opt_model.h"

#define N_STATES 1024
#define REPEATS 7

typedef int (*casadi_fn)(const casadi_real **arg, casadi_real **res, casadi_int *iw, casadi_real *w, int mem);

static casadi_real states[N_STATES][3][2];

static double now_ns(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

/* Uniform in [lo, hi) from a 64-bit LCG: deterministic, no library state. */
static double uniform(unsigned long long *seed, double lo, double hi) {
  *seed = *seed * 6364136223846793005ULL + 1442695040888963407ULL;
  return lo + (hi - lo) * (double)(*seed >> 11) / 9007199254740992.0;
}

static double time_function(const char *name, casadi_fn f, long calls) {
  const casadi_real *arg[3];
  casadi_real out[2];
  casadi_real *res[1];
  casadi_real w[64]; /* larger than any <f>_SZ_W of the generated functions (checked in main) */
  casadi_int iw[1];
  double best = 1e300, checksum = 0.0;
  int r;
  long i;
  res[0] = out;
  for (r = 0; r < REPEATS; ++r) {
    double t0 = now_ns();
    for (i = 0; i < calls; ++i) {
      const long s = i & (N_STATES - 1);
      arg[0] = states[s][0];
      arg[1] = states[s][1];
      arg[2] = states[s][2];
      if (f(arg, res, iw, w, 0) != 0) {
        fprintf(stderr, "%s failed\n", name);
        exit(1);
      }
      checksum += out[0] + out[1];
    }
    {
      const double ns = (now_ns() - t0) / (double)calls;
      if (ns < best) best = ns;
    }
  }
  printf("%s %.3f %.6e\n", name, best, checksum);
  return best;
}

int main(int argc, char **argv) {
  unsigned long long seed = 12345ULL;
  const long calls = argc > 1 ? atol(argv[1]) : 200000L;
  int s;
  if (tau_hat_SZ_W > 64 || tau_hat_gmr_SZ_W > 64 || ddq_hat_SZ_W > 64) {
    fprintf(stderr, "work array too small\n");
    return 1;
  }
  for (s = 0; s < N_STATES; ++s) {
    int j;
    for (j = 0; j < 2; ++j) {
      states[s][0][j] = uniform(&seed, -2.0, 2.0);  /* q [rad] */
      states[s][1][j] = uniform(&seed, -1.5, 1.5);  /* dq [rad/s] */
      states[s][2][j] = uniform(&seed, -5.0, 5.0);  /* ddq [rad/s^2], or tau [N m] for ddq_hat */
    }
  }
  time_function("tau_hat", tau_hat, calls);
  time_function("tau_hat_gmr", tau_hat_gmr, calls);
  time_function("ddq_hat", ddq_hat, calls);
  return 0;
}
