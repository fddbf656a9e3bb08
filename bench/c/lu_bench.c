/* Timing helper for bench/bench_c_runtime.py: repeated factorisations of c*I - J and solves
 * through the integrators' linear solver (dense, or along the model's sparse LU plan). */
#define _POSIX_C_SOURCE 199309L
#include <stdlib.h>
#include <time.h>
#include "bgc_internal.h"

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* seconds per (factorisation + one solve), real (cplx = 0) or complex (cplx = 1) */
double bench_linsys(const bgc_model *m, const double *jv, double c, int reps, int cplx)
{
    bgc_linsys ls;
    if (bgc_linsys_init(&ls, m, cplx)) return -1.0;
    double *b = malloc((size_t)m->n * sizeof(double));
    double complex *bz = malloc((size_t)m->n * sizeof(double complex));
    double t0 = now_s();
    for (int r = 0; r < reps; r++) {
        for (int i = 0; i < m->n; i++) { b[i] = 1.0; bz[i] = 1.0; }
        if (cplx) {
            bgc_linsys_factor_z(&ls, c + 0.5 * c * I, jv);
            bgc_linsys_solve_z(&ls, bz);
        } else {
            bgc_linsys_factor(&ls, c, jv);
            bgc_linsys_solve(&ls, b);
        }
    }
    double dt = (now_s() - t0) / reps;
    free(b); free(bz);
    bgc_linsys_free(&ls);
    return dt;
}
