/* DOP853: Dormand and Prince's explicit Runge-Kutta method of order 8 (Hairer, Norsett &
 * Wanner, Solving ODEs I, sec. II.10), for non-stiff models. Twelve stages a step (the last
 * one's rhs at the step's end is reused as the next step's first), an error estimate that
 * blends the embedded 5th- and 3rd-order solutions, and a 7th-order dense output from three
 * more stages, computed only for a step that has output times in it.
 *
 * The step control is the one scipy's DOP853 uses (safety 0.9, step factors in [0.2, 10],
 * error exponent -1/8, no growth right after a rejection), so a C run and the numpy module's
 * run take comparable steps; the step loop, breakpoints, output sampling, step and wall-time
 * limits and the non-finite checks are the runtime's, shared with Rodas4 and Radau5. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "bgc_internal.h"
#include "bgc_dop853_tab.h"

#define SAFETY 0.9
#define MIN_FACTOR 0.2
#define MAX_FACTOR 10.0
#define EXPONENT (-1.0 / 8.0)

/* The dense output of one step: y(t0 + s h) = y0 + s (F0 + (1-s)(F1 + s (F2 + (1-s)(F3 +
 * s (F4 + (1-s)(F5 + s F6)))))), with F (7 x n) made by dop_dense_coeffs. */
typedef struct { int n; double t0, h; const double *y0, *F; } dop_dense;

static void dop_interp(void *data, double t, double *out)
{
    const dop_dense *d = data;
    const int n = d->n;
    double s = (t - d->t0) / d->h, r = 1.0 - s;
    for (int i = 0; i < n; i++) {
        double v = d->F[6 * (size_t)n + i] * s;
        v = (v + d->F[5 * (size_t)n + i]) * r;
        v = (v + d->F[4 * (size_t)n + i]) * s;
        v = (v + d->F[3 * (size_t)n + i]) * r;
        v = (v + d->F[2 * (size_t)n + i]) * s;
        v = (v + d->F[1 * (size_t)n + i]) * r;
        v = (v + d->F[0 * (size_t)n + i]) * s;
        out[i] = d->y0[i] + v;
    }
}

/* stage s's state: u = y + h sum_{j<s} A[s][j] K_j */
static void dop_stage_state(int n, int s, double h, const double *y, const double *K, double *u)
{
    for (int r = 0; r < n; r++) {
        double acc = 0.0;
        for (int j = 0; j < s; j++)
            if (DOP_A[s][j] != 0.0) acc += DOP_A[s][j] * K[(size_t)j * n + r];
        u[r] = y[r] + h * acc;
    }
}

/* one trial step from (t, y) with K_0 = f(t, y) given: K_1..K_11, ynew, K_12 = f(t+h, ynew).
 * 0, BGC_REJECT (a stage's state or rhs is not finite) or an error status. */
static int dop_step(bgc_ctx *c, double t, double h, const double *y, double *K, double *u,
                    double *ynew)
{
    const int n = c->m->n;
    for (int s = 1; s < DOP_STAGES; s++) {
        dop_stage_state(n, s, h, y, K, u);
        int st = bgc_call_rhs_trial(c, t + DOP_C[s] * h, u, K + (size_t)s * n);
        if (st) return st;
    }
    for (int r = 0; r < n; r++) {
        double acc = 0.0;
        for (int j = 0; j < DOP_STAGES; j++) acc += DOP_B[j] * K[(size_t)j * n + r];
        ynew[r] = y[r] + h * acc;
    }
    return bgc_call_rhs_trial(c, t + h, ynew, K + (size_t)DOP_STAGES * n);
}

/* scipy's DOP853 error norm: |h| e5^2 / sqrt((e5^2 + 0.01 e3^2) n), e5 and e3 the scaled
 * 2-norms of the two embedded error estimates */
static double dop_error(const bgc_ctx *c, double h, const double *K, const double *y,
                        const double *ynew)
{
    const int n = c->m->n;
    double e5 = 0.0, e3 = 0.0;
    for (int r = 0; r < n; r++) {
        double s5 = 0.0, s3 = 0.0;
        for (int j = 0; j <= DOP_STAGES; j++) {
            double k = K[(size_t)j * n + r];
            s5 += DOP_E5[j] * k;
            s3 += DOP_E3[j] * k;
        }
        double a = fabs(y[r]) > fabs(ynew[r]) ? fabs(y[r]) : fabs(ynew[r]);
        double scale = bgc_atol(c, r) + c->rtol * a;
        s5 /= scale; s3 /= scale;
        e5 += s5 * s5; e3 += s3 * s3;
    }
    if (e5 == 0.0 && e3 == 0.0) return 0.0;
    return fabs(h) * e5 / sqrt((e5 + 0.01 * e3) * (n ? n : 1));
}

/* the dense output's coefficients F (7 x n) of the accepted step (t, y) -> (t+h, ynew): three
 * more stages (K_13..K_15) and the D table; 0 or an error status */
static int dop_dense_coeffs(bgc_ctx *c, double t, double h, const double *y,
                            const double *ynew, double *K, double *u, double *F)
{
    const int n = c->m->n;
    for (int s = DOP_STAGES + 1; s < DOP_STAGES_EXT; s++) {
        dop_stage_state(n, s, h, y, K, u);
        int st = bgc_call_rhs(c, t + DOP_C[s] * h, u, K + (size_t)s * n);
        if (st) return st;
    }
    const double *f0 = K, *f1 = K + (size_t)DOP_STAGES * n;
    for (int r = 0; r < n; r++) {
        double dy = ynew[r] - y[r];
        F[r] = dy;
        F[(size_t)n + r] = h * f0[r] - dy;
        F[2 * (size_t)n + r] = 2 * dy - h * (f1[r] + f0[r]);
        for (int i = 0; i < 4; i++) {
            double acc = 0.0;
            for (int j = 0; j < DOP_STAGES_EXT; j++)
                if (DOP_D[i][j] != 0.0) acc += DOP_D[i][j] * K[(size_t)j * n + r];
            F[(size_t)(3 + i) * n + r] = h * acc;
        }
    }
    return 0;
}

int bgc_dop853_segment(bgc_ctx *c, double a, double b, double *y)
{
    const bgc_model *m = c->m;
    const int n = m->n;
    bgc_stats *st = c->st;
    /* K (16n), F (7n), u, ynew, yold (n each), work (2n) */
    double *buf = malloc(((size_t)n * (DOP_STAGES_EXT + 7 + 5) + 1) * sizeof(double));
    if (!buf) return bgc_fail(c, BGC_ERR_ARGS, a, "DOP853: out of memory");
    double *K = buf /* 16n */, *F = K + (size_t)DOP_STAGES_EXT * n /* 7n */,
           *u = F + 7 * (size_t)n, *ynew = u + n, *yold = ynew + n, *work = yold + n /* 2n */;
    double t = a;
    int status;
    if ((status = bgc_call_rhs(c, t, y, K))) goto done;
    double h_abs;
    if (c->opt->h0 > 0) h_abs = c->opt->h0;
    else if ((status = bgc_initial_step(c, t, b, y, K, 7, &h_abs, work))) goto done;
    while (t < b) {
        double min_step = bgc_min_step(t);
        if (h_abs < min_step) h_abs = min_step;
        if (h_abs > c->max_step) h_abs = c->max_step;
        int rejected = 0;
        double err, t_new, h;
        for (;;) {
            if ((status = bgc_attempt(c, t, b, &h_abs, &t_new))) goto done;
            h = h_abs;
            int s = dop_step(c, t, h, y, K, u, ynew);
            if (s && s != BGC_REJECT) { status = s; goto done; }
            err = s == BGC_REJECT ? INFINITY : dop_error(c, h, K, y, ynew);
            if (err < 1.0) break;
            h_abs *= isfinite(err) ? fmax(MIN_FACTOR, SAFETY * pow(err, EXPONENT)) : MIN_FACTOR;
            rejected = 1;
            st->nreject++;
        }
        double fac = err == 0.0 ? MAX_FACTOR : fmin(MAX_FACTOR, SAFETY * pow(err, EXPONENT));
        if (rejected && fac > 1.0) fac = 1.0;
        h_abs *= fac;
        st->naccept++;
        c->pend_index = -1;
        /* dense output only for a step with output times strictly inside it (or events) */
        int inside = c->m->nev > 0 || (c->k_out < c->opt->n_out && c->opt->t_out[c->k_out] < t_new);
        if (inside && (status = dop_dense_coeffs(c, t, h, y, ynew, K, u, F))) goto done;
        memcpy(yold, y, (size_t)n * sizeof(double));
        memcpy(y, ynew, (size_t)n * sizeof(double));
        dop_dense d = {n, t, h, yold, F};
        if ((status = bgc_step_end(c, t, t_new, y, dop_interp, &d))) goto done;
        t = t_new;
        c->xs->t_last = t;
        /* the next step's first stage: the rhs at the step's end (FSAL) */
        memcpy(K, K + (size_t)DOP_STAGES * n, (size_t)n * sizeof(double));
    }
done:
    free(buf);
    return status;
}
