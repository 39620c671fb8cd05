/* Timing loop for the generated tau_hat of an n-joint arm: nanoseconds per call.
 *
 * Built by benchmarks/bench_urdf.py with the generated source, as firmware would be:
 *   cc -O2 -std=c99 -DN_JOINTS=<n> -I<generated dir> bench_urdf.c <dir>/ident_opt_model.c -lm
 * tau_hat is called through a pointer on 1024 distinct random states, cycled; every output feeds a checksum
 * that is printed. The fastest of REPEATS repetitions is reported. Output: "tau_hat <ns per call> <checksum>".
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "ident_opt_model.h"

#define N_STATES 1024
#define REPEATS 7

static casadi_real states[N_STATES][3][N_JOINTS];

static double now_ns(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

static double uniform(unsigned long long *seed, double lo, double hi) {
  *seed = *seed * 6364136223846793005ULL + 1442695040888963407ULL;
  return lo + (hi - lo) * (double)(*seed >> 11) / 9007199254740992.0;
}

int main(int argc, char **argv) {
  const long calls = argc > 1 ? atol(argv[1]) : 100000;
  unsigned long long seed = 1;
  casadi_int sz_arg, sz_res, sz_iw, sz_w;
  const casadi_real *arg[3];
  casadi_real out[N_JOINTS];
  casadi_real *res[1];
  casadi_real *w;
  casadi_int *iw;
  double best = 1e300, checksum = 0.0;
  long i;
  int r, s, j;
  for (s = 0; s < N_STATES; ++s)
    for (j = 0; j < N_JOINTS; ++j) {
      states[s][0][j] = uniform(&seed, -3.0, 3.0);
      states[s][1][j] = uniform(&seed, -2.0, 2.0);
      states[s][2][j] = uniform(&seed, -5.0, 5.0);
    }
  tau_hat_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  w = malloc(sizeof(casadi_real) * (size_t)(sz_w + 1));
  iw = malloc(sizeof(casadi_int) * (size_t)(sz_iw + 1));
  res[0] = out;
  for (r = 0; r < REPEATS; ++r) {
    double t0 = now_ns(), ns;
    for (i = 0; i < calls; ++i) {
      const long k = i & (N_STATES - 1);
      arg[0] = states[k][0];
      arg[1] = states[k][1];
      arg[2] = states[k][2];
      if (tau_hat(arg, res, iw, w, 0) != 0) {
        fprintf(stderr, "tau_hat failed\n");
        return 1;
      }
      for (j = 0; j < N_JOINTS; ++j) checksum += out[j];
    }
    ns = (now_ns() - t0) / (double)calls;
    if (ns < best) best = ns;
  }
  printf("tau_hat %.1f %.6g\n", best, checksum);
  free(w);
  free(iw);
  return 0;
}
