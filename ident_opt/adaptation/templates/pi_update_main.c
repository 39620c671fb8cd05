/* Example: replay a CSV of samples through the generated online update, without Python.
 *
 *   cc -O3 -std=c99 -D_POSIX_C_SOURCE=199309L pi_update_main.c pi_update.c pi_update_casadi.c -o pi_update_example -lm
 *   ./pi_update_example samples.csv [thetas.csv]
 *
 * samples.csv: a header line, then rows $columns [rad, rad/s, rad/s^2, N m] (the
 * columns in this order; any further columns ignored). Starts from the offline fit baked into pi_update.c,
 * folds every row in, and prints one JSON line: samples, updates, failures, the time per update measured
 * over the loop alone (ns: regressor + update; wall clock, and the process's CPU time, which other programs on a
 * busy machine do not inflate), the regressor's own time per sample (ns, a separate loop) and the final
 * parameters. thetas.csv (optional): the parameters after each row. Every buffer is static: no dynamic
 * allocation. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "pi_update.h"
#include "pi_update_casadi.h"

#define MAX_ROWS 200000
#define COLS (4 * PI_UPDATE_J)

static double rows[MAX_ROWS][COLS];
static double thetas[MAX_ROWS][PI_UPDATE_P];
static volatile double sink_out;

static double seconds_since(const struct timespec *t0, clockid_t clock) {
  struct timespec t1;
  clock_gettime(clock, &t1);
  return (t1.tv_sec - t0->tv_sec) + 1e-9 * (t1.tv_nsec - t0->tv_nsec);
}

/* The parameter names are data from the user's files (a URDF's link and joint names): printed escaped, never as
 * they come. json_string: `s` (UTF-8) as a JSON string in plain ASCII: a quote and a backslash backslash-escaped,
 * anything else outside printable ASCII as a u-escape of its code point (a surrogate pair beyond U+FFFF); a byte
 * that is not UTF-8 becomes U+FFFD. */
static void json_string(FILE *out, const char *s) {
  const unsigned char *p = (const unsigned char *)s;
  fputc('"', out);
  while (*p) {
    unsigned long c = *p++;
    int more = 0;
    if (c >= 0xF0 && c <= 0xF4)
      more = 3, c &= 0x07;
    else if (c >= 0xE0 && c <= 0xEF)
      more = 2, c &= 0x0F;
    else if (c >= 0xC2 && c <= 0xDF)
      more = 1, c &= 0x1F;
    else if (c >= 0x80)
      c = 0xFFFD;
    for (; more > 0; --more) {
      if ((*p & 0xC0) != 0x80) {
        c = 0xFFFD;
        break;
      }
      c = (c << 6) | (*p++ & 0x3F);
    }
    if (c > 0x10FFFF) c = 0xFFFD;
    if (c == '"' || c == '\\')
      fprintf(out, "\\%c", (int)c);
    else if (c >= 0x20 && c < 0x7F)
      fputc((int)c, out);
    else if (c < 0x10000)
      fprintf(out, "\\u%04lx", c);
    else
      fprintf(out, "\\u%04lx\\u%04lx", 0xD800 + ((c - 0x10000) >> 10), 0xDC00 + ((c - 0x10000) & 0x3FF));
  }
  fputc('"', out);
}

/* `s` as one CSV field (RFC 4180): as it is unless it holds a comma, a quote or a line break, else quoted with its
 * quotes doubled. */
static void csv_field(FILE *out, const char *s) {
  if (!strpbrk(s, ",\"\r\n")) {
    fputs(s, out);
    return;
  }
  fputc('"', out);
  for (; *s; ++s) {
    if (*s == '"') fputc('"', out);
    fputc(*s, out);
  }
  fputc('"', out);
}

/* ns per call of the regressor alone over the rows (what pi_update spends before the update proper). */
static double regressor_ns(long n) {
  static double Y[PI_UPDATE_J * PI_UPDATE_P];
  const double *arg[pi_regressor_SZ_ARG + 1];
  double *res[pi_regressor_SZ_RES + 1];
  casadi_int iw[pi_regressor_SZ_IW + 1];
  double w[pi_regressor_SZ_W + 1], sink = 0.0;
  struct timespec t0;
  clock_gettime(CLOCK_MONOTONIC, &t0);
  for (long k = 0; k < n; ++k) {
    arg[0] = rows[k];
    arg[1] = rows[k] + PI_UPDATE_J;
    arg[2] = rows[k] + 2 * PI_UPDATE_J;
    res[0] = Y;
    pi_regressor(arg, res, iw, w, 0);
    sink += Y[k % (PI_UPDATE_J * PI_UPDATE_P)];
  }
  sink_out = sink; /* keeps the loop from being optimised away */
  return seconds_since(&t0, CLOCK_MONOTONIC) * 1e9 / (n > 0 ? n : 1);
}

int main(int argc, char **argv) {
  if (argc < 2) {
    fprintf(stderr, "usage: %s samples.csv [thetas.csv]\n", argv[0]);
    return 2;
  }
  FILE *in = fopen(argv[1], "r");
  if (!in) {
    perror(argv[1]);
    return 2;
  }
  static char line[1 << 16];
  long n = 0;
  if (!fgets(line, sizeof line, in)) return 2; /* the header */
  while (n < MAX_ROWS && fgets(line, sizeof line, in)) {
    char *p = line, *end;
    int c;
    for (c = 0; c < COLS; ++c) {
      rows[n][c] = strtod(p, &end);
      if (end == p) break;
      p = (*end == ',') ? end + 1 : end;
    }
    if (c == COLS) ++n;
  }
  fclose(in);

  static pi_update_state s;
  pi_update_initial(&s);
  long failed = 0;
  struct timespec t0, c0;
  clock_gettime(CLOCK_MONOTONIC, &t0);
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &c0);
  for (long k = 0; k < n; ++k) {
    const double *r = rows[k];
    if (pi_update(&s, r, r + PI_UPDATE_J, r + 2 * PI_UPDATE_J, r + 3 * PI_UPDATE_J) != 0) ++failed;
    for (int p = 0; p < PI_UPDATE_P; ++p) thetas[k][p] = s.theta[p];
  }
  double cpu_ns = seconds_since(&c0, CLOCK_PROCESS_CPUTIME_ID) * 1e9 / (n > 0 ? n : 1);
  double ns = seconds_since(&t0, CLOCK_MONOTONIC) * 1e9 / (n > 0 ? n : 1);
  double ns_regressor = regressor_ns(n);

  if (argc > 2) {
    FILE *out = fopen(argv[2], "w");
    if (!out) {
      perror(argv[2]);
      return 2;
    }
    for (int p = 0; p < PI_UPDATE_P; ++p) {
      csv_field(out, PI_UPDATE_NAMES[p]);
      fputs(p + 1 < PI_UPDATE_P ? "," : "\n", out);
    }
    for (long k = 0; k < n; ++k)
      for (int p = 0; p < PI_UPDATE_P; ++p) fprintf(out, "%.17g%s", thetas[k][p], p + 1 < PI_UPDATE_P ? "," : "\n");
    fclose(out);
  }
  printf("{\"samples\": %ld, \"updates\": %ld, \"failed\": %ld, \"ns_per_update\": %.1f, \"cpu_ns_per_update\": "
         "%.1f, \"ns_regressor\": %.1f, \"parameters\": {",
         n, n - failed, failed, ns, cpu_ns, ns_regressor);
  for (int p = 0; p < PI_UPDATE_P; ++p) {
    json_string(stdout, PI_UPDATE_NAMES[p]);
    printf(": %.17g%s", s.theta[p], p + 1 < PI_UPDATE_P ? ", " : "}}\n");
  }
  return failed ? 1 : 0;
}
