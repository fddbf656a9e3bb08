/* Rodas4: the 6-stage Rosenbrock method of order 4 (embedded order 3) of Hairer & Wanner
 * (Solving ODEs II, sec. IV.7; coefficients of their RODAS), L-stable and stiffly accurate,
 * with a dense output of order 3. The same method and step control as the numpy module's
 * Rodas4: each step costs one Jacobian, one LU of W = I/(h gamma) - J and six rhs calls (one
 * more for df/dt, by a forward difference, when the model has time inputs). */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "bgc_internal.h"

#define GAMMA 0.25
static const double RA[6][5] = { /* stage i's state: y + sum_j A[i][j] k_j */
    {0, 0, 0, 0, 0},
    {1.544, 0, 0, 0, 0},
    {0.9466785280815826, 0.2557011698983284, 0, 0, 0},
    {3.314825187068521, 2.896124015972201, 0.9986419139977817, 0, 0},
    {1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 0},
    {1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 1.0},
};
static const double RC[6][5] = { /* stage i's rhs: f_i + sum_j C[i][j] k_j / h + h d_i df/dt */
    {0, 0, 0, 0, 0},
    {-5.6688, 0, 0, 0, 0},
    {-2.430093356833875, -0.2063599157091915, 0, 0, 0},
    {-0.1073529058151375, -9.594562251023355, -20.47028614809616, 0, 0},
    {7.496443313967647, -10.24680431464352, -33.99990352819905, 11.7089089320616, 0},
    {8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136,
     -6.058818238834054},
};
static const double RT[6] = {0.0, 0.386, 0.21, 0.63, 1.0, 1.0};
static const double RD[6] = {0.25, -0.1043, 0.1035, -0.0362, 0.0, 0.0};
static const double RH[2][5] = { /* dense: y(s) = (1-s) y0 + s (y1 + (1-s)(q1 + s q2)) */
    {10.12623508344586, -7.487995877610167, -34.80091861555747, -7.992771707568823,
     1.025137723295662},
    {-0.6762803392801253, 6.087714651680015, 16.43084320892478, 24.76722511418386,
     -6.594389125716872},
};
#define SAFETY 0.9
#define MIN_FACTOR 0.2
#define MAX_FACTOR 6.0

typedef struct { int n; double t0, h; const double *y0, *y1, *q; } rodas_dense;

static void rodas_interp(void *data, double t, double *out)
{
    const rodas_dense *d = data;
    double s = (t - d->t0) / d->h;
    const double *q1 = d->q, *q2 = d->q + d->n;
    for (int i = 0; i < d->n; i++)
        out[i] = (1 - s) * d->y0[i] + s * (d->y1[i] + (1 - s) * (q1[i] + s * q2[i]));
}

int bgc_rodas4_segment(bgc_ctx *c, double a, double b, double *y)
{
    const bgc_model *m = c->m;
    const int n = m->n;
    bgc_stats *st = c->st;
    double *buf = malloc(((size_t)n * 16 + (size_t)m->nnz + 1) * sizeof(double));
    bgc_linsys ls;
    int status = bgc_linsys_init(&ls, m, 0);
    if (!buf || status) {
        free(buf); bgc_linsys_free(&ls);
        return bgc_fail(c, BGC_ERR_ARGS, a, "Rodas4: out of memory");
    }
    double *f = buf, *dfdt = f + n, *K = dfdt + n /* 6n */, *u = K + 6 * (size_t)n,
           *ynew = u + n, *rhs = ynew + n, *q = rhs + n /* 2n */, *yold = q + 2 * (size_t)n,
           *work = yold + n /* 2n */, *jv = work + 2 * (size_t)n;
    double t = a;
    if ((status = bgc_call_rhs(c, t, y, f))) goto done;
    double h_abs;
    if (c->opt->h0 > 0) h_abs = c->opt->h0;
    else if ((status = bgc_initial_step(c, t, b, y, f, 4, &h_abs, work))) goto done;
    while (t < b) {
        double min_step = bgc_min_step(t);
        if (h_abs < min_step) h_abs = min_step;
        if (h_abs > c->max_step) h_abs = c->max_step;
        /* J and df/dt at the step's start, kept through rejected attempts */
        if ((status = bgc_call_jac(c, t, y, jv))) goto done;
        memset(dfdt, 0, (size_t)n * sizeof(double));
        if (m->has_time_inputs) {
            double d = sqrt(2.220446049250313e-16) * fmax(1.0, fabs(t));
            if (t + d > b) d = -d;
            if ((status = bgc_call_rhs(c, t + d, y, dfdt))) goto done;
            for (int i = 0; i < n; i++) dfdt[i] = (dfdt[i] - f[i]) / d;
        }
        int rejected = 0;
        double err_norm, t_new, h;
        for (;;) {
            if ((status = bgc_attempt(c, t, b, &h_abs, &t_new))) goto done;
            h = h_abs;
            st->nlu++;
            err_norm = INFINITY;
            if (bgc_linsys_factor(&ls, 1.0 / (h * GAMMA), jv) == 0) {
                int ok = 1;
                for (int i = 0; i < 6 && ok; i++) {
                    double *ki = K + (size_t)i * n;
                    for (int r = 0; r < n; r++) {
                        double su = y[r], sc = 0.0;
                        for (int j = 0; j < i; j++) {
                            su += RA[i][j] * K[(size_t)j * n + r];
                            sc += RC[i][j] * K[(size_t)j * n + r];
                        }
                        u[r] = su;
                        rhs[r] = sc / h + h * RD[i] * dfdt[r];
                    }
                    if (i == 0) memcpy(ki, f, (size_t)n * sizeof(double));
                    else {
                        int s = bgc_call_rhs_trial(c, t + RT[i] * h, u, ki);
                        if (s == BGC_REJECT) { ok = 0; break; }
                        if (s) { status = s; goto done; }
                    }
                    for (int r = 0; r < n; r++) ki[r] += rhs[r];
                    bgc_linsys_solve(&ls, ki);
                }
                if (ok) {
                    const double *k6 = K + 5 * (size_t)n;
                    for (int r = 0; r < n; r++) ynew[r] = u[r] + k6[r];
                    err_norm = bgc_err_norm(c, k6, y, ynew);
                }
            }
            if (isfinite(err_norm) && err_norm <= 1.0) break;
            double fac = !isfinite(err_norm) ? MIN_FACTOR
                         : fmax(MIN_FACTOR, SAFETY * pow(err_norm, -0.25));
            h_abs *= fac;
            rejected = 1;
            st->nreject++;
        }
        double fac = err_norm == 0 ? MAX_FACTOR : fmin(MAX_FACTOR, SAFETY * pow(err_norm, -0.25));
        if (rejected && fac > 1.0) fac = 1.0;
        h_abs *= fmax(MIN_FACTOR, fac);
        st->naccept++;
        c->pend_index = -1;
        for (int r = 0; r < n; r++) {
            double s1 = 0.0, s2 = 0.0;
            for (int j = 0; j < 5; j++) {
                s1 += RH[0][j] * K[(size_t)j * n + r];
                s2 += RH[1][j] * K[(size_t)j * n + r];
            }
            q[r] = s1; q[n + r] = s2;
        }
        memcpy(yold, y, (size_t)n * sizeof(double));
        memcpy(y, ynew, (size_t)n * sizeof(double));
        rodas_dense d = {n, t, h, yold, y, q};
        if ((status = bgc_step_end(c, t, t_new, y, rodas_interp, &d))) goto done;
        t = t_new;
        c->xs->t_last = t;
        if (t < b && (status = bgc_call_rhs(c, t, y, f))) goto done;
    }
done:
    c->xs->nsparse_fallback += ls.fallbacks;
    bgc_linsys_free(&ls);
    free(buf);
    return status;
}
