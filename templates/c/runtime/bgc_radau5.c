/* Radau IIA of order 5: the 3-stage implicit Runge-Kutta collocation method at the Radau
 * points c = (4-sqrt6)/10, (4+sqrt6)/10, 1 (Hairer & Wanner, Solving ODEs II, sec. IV.8).
 * The stage equations Z = h (A x I) F(y0 + Z) are solved by a simplified Newton iteration
 * in the variables W = (T^-1 x I) Z that split the iteration matrix into one real system
 * (gamma/h I - J) and one complex system ((alpha + i beta)/h I - J), where
 * T^-1 A^-1 T = [[gamma, 0, 0], [0, alpha, -beta], [0, beta, alpha]]. The error estimate is
 * the embedded order-3 formula of H&W (8.19)-(8.20), filtered through (gamma/h I - J)^-1;
 * the step size follows the predictive (Gustafsson) controller; dense output and the Newton
 * starting values come from the collocation polynomial.
 *
 * The constants below were computed from these definitions in 40-digit arithmetic (T's
 * eigenvector columns scaled to a last component of 1); tests/test_c_runtime.py checks them
 * against the collocation matrix. */
#include <complex.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "bgc_internal.h"

#define SQ6 2.449489742783178098197284
static const double C1 = (4.0 - SQ6) / 10.0, C2 = (4.0 + SQ6) / 10.0;
static const double GAM = 3.63783425274449573221;   /* the real eigenvalue of A^-1 */
static const double ALPHA = 2.6810828736277521339;  /* the complex pair alpha +- i beta */
static const double BETA = 3.05043019924741056943;
static const double TM[3][3] = {
    {0.0944387624889752414875, -0.141255295020954208428, -0.0300291941051474244919},
    {0.250213122965333311377, 0.204129352293799931996, 0.382942112757261937795},
    {1.0, 1.0, 0.0},
};
static const double TI[3][3] = {
    {4.17871859155190472735, 0.327682820761062387083, 0.52337644549944954804},
    {-4.17871859155190472735, -0.327682820761062387083, 0.47662355450055045196},
    {-0.502872634945786875951, 2.57192694985560542919, -0.596039204828224924969},
};
/* error estimate: err = (gamma/h I - J)^-1 (f(y0) + (E1 z1 + E2 z2 + E3 z3) / h) */
static const double E1 = -(13.0 + 7.0 * SQ6) / 3.0, E2 = (-13.0 + 7.0 * SQ6) / 3.0,
                    E3 = -1.0 / 3.0;
#define NEWTON_MAXITER 7
#define SAFETY 0.9
#define MIN_FACTOR 0.2
#define MAX_FACTOR 8.0
#define JAC_KEEP 1e-3   /* keep J after a step whose Newton needed at most 2 iterations or
                          contracted at least this fast */
/* With J kept, the step size stays (and the LU with it) unless the controller asks for more
 * than FREEZE_MAX times it. Hairer's RADAU5 keeps h for 1 <= h_new/h <= 1.2 by default and
 * advises up to 2 where an LU costs much more than f; here one rhs call costs 0.2 us and an
 * LU pair of the 3R2S 70 us. Measured on the example scenes (python bench/bench_radau_window.py,
 * docs/c-runtime.md): 1.6 takes the 3R2S circle from 569 LU pairs and 251 rejected steps to
 * 206 and 79, about 35 % less time, at an equal or smaller error; 2.0 takes more steps than it
 * saves LUs. */
#ifndef BGC_RADAU_FREEZE_MAX  /* (bench/bench_radau_window.py builds other windows) */
#define BGC_RADAU_FREEZE_MAX 1.6
#endif
#define FREEZE_MAX BGC_RADAU_FREEZE_MAX

/* the collocation polynomial of a step: y0 + sum_i Z_i L_i(s), s = (t - t0)/h, L_i the
 * Lagrange polynomials on the nodes 0, c1, c2, 1 that vanish at 0 */
typedef struct { int n; double t0, h; const double *y0, *Z; } radau_dense;

static void lagrange(double s, double L[3])
{
    const double c[3] = {C1, C2, 1.0};
    for (int i = 0; i < 3; i++) {
        double num = s, den = c[i];
        for (int j = 0; j < 3; j++)
            if (j != i) { num *= s - c[j]; den *= c[i] - c[j]; }
        L[i] = num / den;
    }
}

static void radau_interp(void *data, double t, double *out)
{
    const radau_dense *d = data;
    double L[3];
    lagrange((t - d->t0) / d->h, L);
    const int n = d->n;
    for (int r = 0; r < n; r++)
        out[r] = d->y0[r] + L[0] * d->Z[r] + L[1] * d->Z[n + r] + L[2] * d->Z[2 * n + r];
}

int bgc_radau5_segment(bgc_ctx *c, double a, double b, double *y)
{
    const bgc_model *m = c->m;
    const int n = m->n;
    const size_t N = (size_t)n;
    bgc_stats *st = c->st;
    double *buf = malloc((N * 24 + (size_t)m->nnz + 1) * sizeof(double));
    double complex *v = malloc((N + 1) * sizeof(double complex));
    bgc_linsys ls;
    int status = bgc_linsys_init(&ls, m, 1);
    if (!buf || !v || status) {
        free(buf); free(v); bgc_linsys_free(&ls);
        return bgc_fail(c, BGC_ERR_ARGS, a, "Radau5: out of memory");
    }
    double *f0 = buf, *Z = f0 + N /* 3n */, *W = Z + 3 * N /* 3n */, *F = W + 3 * N /* 3n */,
           *dW = F + 3 * N /* 3n */, *ynew = dW + 3 * N, *err = ynew + N, *tmp = err + N,
           *scal = tmp + N, *yold = scal + N, *Zold = yold + N /* 3n */,
           *work = Zold + 3 * N /* 2n */, *jv = work + 2 * N;
    double t = a;
    if ((status = bgc_call_rhs(c, t, y, f0))) goto done;
    double h_abs;
    if (c->opt->h0 > 0) h_abs = c->opt->h0;
    else if ((status = bgc_initial_step(c, t, b, y, f0, 3, &h_abs, work))) goto done;
    int jac_current = 0, have_lu = 0, have_prev = 0;
    double h_lu = 0.0, h_prev = 0.0, h_acc = 0.0, err_acc = 0.0, eta = 1.0;
    int have_acc = 0;
    /* Newton tolerance on the scaled increment (Hairer's fnewt) */
    double eps = 2.220446049250313e-16;
    double tol_newton = fmax(10 * eps / c->rtol, fmin(0.03, sqrt(c->rtol)));
    if ((status = bgc_call_jac(c, t, y, jv))) goto done;
    jac_current = 1;
    int first = 1;
    while (t < b) {
        if (h_abs > c->max_step) h_abs = c->max_step;
        int rejected = 0;
        double h, t_new, err_norm = 0.0, theta = 0.0;
        int niter = 0;
        for (;;) {
            if ((status = bgc_attempt(c, t, b, &h_abs, &t_new))) goto done;
            h = h_abs;
            if (!have_lu || h != h_lu) {
                st->nlu += 2;
                int s1 = bgc_linsys_factor(&ls, GAM / h, jv);
                int s2 = bgc_linsys_factor_z(&ls, (ALPHA + I * BETA) / h, jv);
                have_lu = !(s1 || s2);
                h_lu = h;
                if (!have_lu) {  /* singular: try a smaller step */
                    h_abs *= 0.5; rejected = 1; st->nreject++;
                    continue;
                }
            }
            /* starting values: the previous step's collocation polynomial, else zero */
            if (have_prev) {
                const double cc[3] = {C1, C2, 1.0};
                for (int i = 0; i < 3; i++) {
                    double L[3];
                    lagrange(1.0 + cc[i] * h / h_prev, L);
                    for (size_t r = 0; r < N; r++)
                        Z[i * N + r] = yold[r] + L[0] * Zold[r] + L[1] * Zold[N + r] +
                                       L[2] * Zold[2 * N + r] - y[r];
                }
            } else memset(Z, 0, 3 * N * sizeof(double));
            for (size_t r = 0; r < N; r++)
                for (int i = 0; i < 3; i++)
                    W[i * N + r] = TI[i][0] * Z[r] + TI[i][1] * Z[N + r] + TI[i][2] * Z[2 * N + r];
            for (int i = 0; i < n; i++) scal[i] = bgc_atol(c, i) + c->rtol * fabs(y[i]);
            /* simplified Newton iteration */
            int converged = 0, diverged = 0;
            double dnorm_old = 0.0;
            eta = pow(fmax(eta, eps), 0.8);
            theta = 0.0;
            for (niter = 1; niter <= NEWTON_MAXITER; niter++) {
                const double cc[3] = {C1, C2, 1.0};
                for (int i = 0; i < 3; i++) {
                    for (size_t r = 0; r < N; r++) tmp[r] = y[r] + Z[i * N + r];
                    int s = bgc_call_rhs_trial(c, t + cc[i] * h, tmp, F + i * N);
                    if (s == BGC_REJECT) { diverged = 1; break; }
                    if (s) { status = s; goto done; }
                }
                if (diverged) break;
                double dsum = 0.0;
                for (size_t r = 0; r < N; r++) {
                    double g1 = TI[0][0] * F[r] + TI[0][1] * F[N + r] + TI[0][2] * F[2 * N + r];
                    double g2 = TI[1][0] * F[r] + TI[1][1] * F[N + r] + TI[1][2] * F[2 * N + r];
                    double g3 = TI[2][0] * F[r] + TI[2][1] * F[N + r] + TI[2][2] * F[2 * N + r];
                    double w1 = W[r], w2 = W[N + r], w3 = W[2 * N + r];
                    dW[r] = g1 - GAM / h * w1;
                    v[r] = (g2 - (ALPHA * w2 - BETA * w3) / h) + I * (g3 - (BETA * w2 + ALPHA * w3) / h);
                }
                bgc_linsys_solve(&ls, dW);
                bgc_linsys_solve_z(&ls, v);
                for (size_t r = 0; r < N; r++) {
                    dW[N + r] = creal(v[r]);
                    dW[2 * N + r] = cimag(v[r]);
                    for (int i = 0; i < 3; i++) {
                        double q = dW[i * N + r] / scal[r];
                        dsum += q * q;
                    }
                }
                double dnorm = n ? sqrt(dsum / (3.0 * n)) : 0.0;
                if (!isfinite(dnorm)) { diverged = 1; break; }
                if (niter > 1) {
                    theta = dnorm / dnorm_old;
                    if (theta >= 0.99) { diverged = 1; break; }
                    /* the contraction would not reach the tolerance within the iterations left */
                    if (pow(theta, NEWTON_MAXITER - niter) / (1 - theta) * dnorm > tol_newton) {
                        diverged = 1; break;
                    }
                    eta = theta / (1 - theta);
                }
                dnorm_old = dnorm;
                for (size_t k = 0; k < 3 * N; k++) W[k] += dW[k];
                for (size_t r = 0; r < N; r++)
                    for (int i = 0; i < 3; i++)
                        Z[i * N + r] = TM[i][0] * W[r] + TM[i][1] * W[N + r] + TM[i][2] * W[2 * N + r];
                if (eta * dnorm <= tol_newton || dnorm == 0.0) { converged = 1; break; }
            }
            if (!converged) {
                st->nreject++;
                rejected = 1;
                if (!jac_current) {  /* a fresh Jacobian at the same step size */
                    if ((status = bgc_call_jac(c, t, y, jv))) goto done;
                    jac_current = 1;
                    have_lu = 0;
                } else {
                    h_abs *= 0.5;
                }
                eta = 1.0;
                continue;
            }
            /* error estimate */
            for (size_t r = 0; r < N; r++) {
                ynew[r] = y[r] + Z[2 * N + r];
                tmp[r] = (E1 * Z[r] + E2 * Z[N + r] + E3 * Z[2 * N + r]) / h;
                err[r] = f0[r] + tmp[r];
            }
            bgc_linsys_solve(&ls, err);
            err_norm = bgc_err_norm(c, err, y, ynew);
            if (err_norm >= 1.0 && (first || rejected)) {
                /* Hairer's remedy for stiff components: one more filtering with f(y0 + err) */
                for (size_t r = 0; r < N; r++) work[r] = y[r] + err[r];
                int s = bgc_call_rhs_trial(c, t, work, err);
                if (s && s != BGC_REJECT) { status = s; goto done; }
                if (s == BGC_REJECT) err_norm = INFINITY;
                else {
                    for (size_t r = 0; r < N; r++) err[r] += tmp[r];
                    bgc_linsys_solve(&ls, err);
                    err_norm = bgc_err_norm(c, err, y, ynew);
                }
            }
            if (isfinite(err_norm) && err_norm <= 1.0) break;
            double safety = SAFETY * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + niter);
            double fac = isfinite(err_norm) ? fmax(MIN_FACTOR, safety * pow(err_norm, -0.25))
                                            : MIN_FACTOR;
            h_abs *= fac;
            rejected = 1;
            st->nreject++;
        }
        /* accepted: the next step size (predictive controller, H&W IV.8 (8.25)) */
        st->naccept++;
        c->pend_index = -1;
        first = 0;
        double safety = SAFETY * (2 * NEWTON_MAXITER + 1) / (2 * NEWTON_MAXITER + niter);
        double en = fmax(err_norm, 1e-10);
        double fac = safety * pow(en, -0.25);
        if (have_acc) {
            double pred = h / h_acc * pow(err_acc / en, 0.25) * safety * pow(en, -0.25);
            if (pred < fac) fac = pred;
        }
        fac = fmin(MAX_FACTOR, fmax(MIN_FACTOR, fac));
        if (rejected && fac > 1.0) fac = 1.0;
        h_acc = h; err_acc = fmax(en, 1e-2); have_acc = 1;
        /* keep J (and the LU when the step size hardly changes) after fast convergence */
        int keep_jac = niter <= 2 || theta <= JAC_KEEP;
        double h_next = h * fac;
        if (keep_jac && fac <= FREEZE_MAX) h_next = h;
        memcpy(yold, y, N * sizeof(double));
        memcpy(Zold, Z, 3 * N * sizeof(double));
        h_prev = h;
        have_prev = 1;
        memcpy(y, ynew, N * sizeof(double));
        radau_dense d = {n, t, h, yold, Zold};
        if ((status = bgc_step_end(c, t, t_new, y, radau_interp, &d))) goto done;
        t = t_new;
        c->xs->t_last = t;
        h_abs = h_next;
        if (t < b) {
            if ((status = bgc_call_rhs(c, t, y, f0))) goto done;
            if (!keep_jac) {
                if ((status = bgc_call_jac(c, t, y, jv))) goto done;
                jac_current = 1;
                have_lu = 0;
            } else jac_current = 0;
        }
    }
done:
    c->xs->nsparse_fallback += ls.fallbacks;
    bgc_linsys_free(&ls);
    free(v);
    free(buf);
    return status;
}

/* the method's constants, for tests: c1, c2, gamma, alpha, beta, T (row-major), T^-1, E1..E3 */
void bgc_radau5_constants(double *out)
{
    out[0] = C1; out[1] = C2; out[2] = GAM; out[3] = ALPHA; out[4] = BETA;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) { out[5 + 3 * i + j] = TM[i][j]; out[14 + 3 * i + j] = TI[i][j]; }
    out[23] = E1; out[24] = E2; out[25] = E3;
}
