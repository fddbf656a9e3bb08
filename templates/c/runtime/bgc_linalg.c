/* bgc runtime: dense LU with partial pivoting (real and complex) and the sparse LU that
 * follows a plan made at code-generation time (bgc.sparse_lu): no pivoting, elimination
 * positions precomputed, as KPP's generated Rosenbrock solvers do. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "bgc_internal.h"

#define BGC_PIVOT_REL 1e-10 /* sparse pivot accepted when |u_kk| > this * max|row k| */

int bgc_dense_lu(int n, double *a, int *piv)
{
    int info = 0;
    for (int k = 0; k < n; k++) {
        int p = k;
        double best = fabs(a[(size_t)k * n + k]);
        for (int i = k + 1; i < n; i++) {
            double v = fabs(a[(size_t)i * n + k]);
            if (v > best) { best = v; p = i; }
        }
        piv[k] = p;
        if (!(best > 0.0)) { if (!info) info = k + 1; continue; }
        if (p != k) {
            double *rk = a + (size_t)k * n, *rp = a + (size_t)p * n;
            for (int j = 0; j < n; j++) { double t = rk[j]; rk[j] = rp[j]; rp[j] = t; }
        }
        const double *rk = a + (size_t)k * n;
        double inv = 1.0 / rk[k];
        for (int i = k + 1; i < n; i++) {
            double *ri = a + (size_t)i * n;
            double l = ri[k] * inv;
            ri[k] = l;
            if (l != 0.0)
                for (int j = k + 1; j < n; j++) ri[j] -= l * rk[j];
        }
    }
    return info;
}

void bgc_dense_solve(int n, const double *lu, const int *piv, double *b)
{
    for (int k = 0; k < n; k++) {
        int p = piv[k];
        if (p != k) { double t = b[k]; b[k] = b[p]; b[p] = t; }
    }
    for (int i = 1; i < n; i++) {
        const double *ri = lu + (size_t)i * n;
        double s = b[i];
        for (int j = 0; j < i; j++) s -= ri[j] * b[j];
        b[i] = s;
    }
    for (int i = n - 1; i >= 0; i--) {
        const double *ri = lu + (size_t)i * n;
        double s = b[i];
        for (int j = i + 1; j < n; j++) s -= ri[j] * b[j];
        b[i] = s / ri[i];
    }
}

/* x = A^-1 b for the model's numeric linear solves (derivative causality, Newton loops):
 * bgc_dense_lu (partial pivoting) above, then its solve; a (n x n, row-major) and b
 * overwritten, b by x. 0, or k+1 when pivot k is exactly zero (singular; b is then left as it was).
 * No allocation: safe to call from many threads on their own arrays. */
int bgc_dense_linsolve(int n, double *a, double *b)
{
    int piv[n > 0 ? n : 1];  /* the systems are small (a limit of the model format): stack */
    int info = bgc_dense_lu(n, a, piv);
    if (!info) bgc_dense_solve(n, a, piv, b);
    return info;
}

static double cabs1(double complex z) { return fabs(creal(z)) + fabs(cimag(z)); }

int bgc_dense_lu_z(int n, double complex *a, int *piv)
{
    int info = 0;
    for (int k = 0; k < n; k++) {
        int p = k;
        double best = cabs1(a[(size_t)k * n + k]);
        for (int i = k + 1; i < n; i++) {
            double v = cabs1(a[(size_t)i * n + k]);
            if (v > best) { best = v; p = i; }
        }
        piv[k] = p;
        if (!(best > 0.0)) { if (!info) info = k + 1; continue; }
        if (p != k) {
            double complex *rk = a + (size_t)k * n, *rp = a + (size_t)p * n;
            for (int j = 0; j < n; j++) { double complex t = rk[j]; rk[j] = rp[j]; rp[j] = t; }
        }
        const double complex *rk = a + (size_t)k * n;
        double complex inv = 1.0 / rk[k];
        for (int i = k + 1; i < n; i++) {
            double complex *ri = a + (size_t)i * n;
            double complex l = ri[k] * inv;
            ri[k] = l;
            if (l != 0.0)
                for (int j = k + 1; j < n; j++) ri[j] -= l * rk[j];
        }
    }
    return info;
}

void bgc_dense_solve_z(int n, const double complex *lu, const int *piv, double complex *b)
{
    for (int k = 0; k < n; k++) {
        int p = piv[k];
        if (p != k) { double complex t = b[k]; b[k] = b[p]; b[p] = t; }
    }
    for (int i = 1; i < n; i++) {
        const double complex *ri = lu + (size_t)i * n;
        double complex s = b[i];
        for (int j = 0; j < i; j++) s -= ri[j] * b[j];
        b[i] = s;
    }
    for (int i = n - 1; i >= 0; i--) {
        const double complex *ri = lu + (size_t)i * n;
        double complex s = b[i];
        for (int j = i + 1; j < n; j++) s -= ri[j] * b[j];
        b[i] = s / ri[i];
    }
}

/* ---- sparse, along the plan ---------------------------------------------------------------- */
/* The factors overwrite a in the plan's L+U layout, each pivot stored as its reciprocal: the
 * elimination and the back substitution then multiply (a division per entry, and C99's
 * complex division with its inf/nan cases, cost a tenth of a Radau run on the 3R2S). */

/* 1/z for a finite, nonzero z (the pivot test has passed): no library call */
static double complex recip_z(double complex z)
{
    double re = creal(z), im = cimag(z);
    if (fabs(re) >= fabs(im)) {  /* Smith's scaling: no overflow in re*re + im*im */
        double r = im / re, den = re + im * r;
        return (1.0 / den) + I * (-r / den);
    }
    double r = re / im, den = re * r + im;
    return (r / den) + I * (-1.0 / den);
}

int bgc_sparse_lu(const struct bgc_lu_plan *pl, double *a)
{
    const int *rp = pl->row_ptr, *ci = pl->col_idx, *dp = pl->diag_pos, *tg = pl->elim_tgt;
    int q = 0;
    for (int i = 0; i < pl->n; i++) {
        double rmax = 0.0;
        for (int e = rp[i]; e < rp[i + 1]; e++) {
            double v = fabs(a[e]);
            if (v > rmax) rmax = v;
        }
        for (int e = rp[i]; e < dp[i]; e++) {
            int k = ci[e];
            double l = a[e] * a[dp[k]];  /* row k's pivot is stored as its reciprocal */
            a[e] = l;
            for (int s = dp[k] + 1; s < rp[k + 1]; s++) a[tg[q++]] -= l * a[s];
        }
        double d = fabs(a[dp[i]]);
        if (!(d > BGC_PIVOT_REL * rmax) || !isfinite(d)) return i + 1;
        a[dp[i]] = 1.0 / a[dp[i]];
    }
    return 0;
}

void bgc_sparse_solve(const struct bgc_lu_plan *pl, const double *a, double *b, double *w)
{
    const int n = pl->n, *rp = pl->row_ptr, *ci = pl->col_idx, *dp = pl->diag_pos;
    for (int i = 0; i < n; i++) {
        double s = b[pl->perm[i]];
        for (int e = rp[i]; e < dp[i]; e++) s -= a[e] * w[ci[e]];
        w[i] = s;
    }
    for (int i = n - 1; i >= 0; i--) {
        double s = w[i];
        for (int e = dp[i] + 1; e < rp[i + 1]; e++) s -= a[e] * w[ci[e]];
        w[i] = s * a[dp[i]];
    }
    for (int i = 0; i < n; i++) b[pl->perm[i]] = w[i];
}

/* The complex kernels below work on the factors as (re, im) pairs of doubles (the layout
 * C99 6.2.5 gives a double complex) with the products written out: C99's complex `*` checks
 * every product for NaN and calls __muldc3 to recover infinities (Annex G), which made these
 * loops a fifth slower. The values here are finite (each pivot is tested); a NaN or infinity
 * in the input still gives a non-finite result, which the integrator's error test rejects. */
int bgc_sparse_lu_z(const struct bgc_lu_plan *pl, double complex *az)
{
    const int *rp = pl->row_ptr, *ci = pl->col_idx, *dp = pl->diag_pos, *tg = pl->elim_tgt;
    double *a = (double *)az;
    int q = 0;
    for (int i = 0; i < pl->n; i++) {
        double rmax = 0.0;
        for (int e = rp[i]; e < rp[i + 1]; e++) {
            double v = fabs(a[2 * e]) + fabs(a[2 * e + 1]);
            if (v > rmax) rmax = v;
        }
        for (int e = rp[i]; e < dp[i]; e++) {
            const double *pk = a + 2 * (size_t)dp[ci[e]];  /* row k's reciprocal pivot */
            double er = a[2 * e], ei = a[2 * e + 1];
            double lr = er * pk[0] - ei * pk[1], li = er * pk[1] + ei * pk[0];
            a[2 * e] = lr;
            a[2 * e + 1] = li;
            for (int s = dp[ci[e]] + 1; s < rp[ci[e] + 1]; s++) {
                double sr = a[2 * s], si = a[2 * s + 1];
                double *t = a + 2 * (size_t)tg[q++];
                t[0] -= lr * sr - li * si;
                t[1] -= lr * si + li * sr;
            }
        }
        double *d = a + 2 * (size_t)dp[i];
        double dn = fabs(d[0]) + fabs(d[1]);
        if (!(dn > BGC_PIVOT_REL * rmax) || !isfinite(dn)) return i + 1;
        double complex r = recip_z(d[0] + I * d[1]);
        d[0] = creal(r);
        d[1] = cimag(r);
    }
    return 0;
}

void bgc_sparse_solve_z(const struct bgc_lu_plan *pl, const double complex *az,
                        double complex *bz, double complex *wz)
{
    const int n = pl->n, *rp = pl->row_ptr, *ci = pl->col_idx, *dp = pl->diag_pos;
    const double *a = (const double *)az;
    double *b = (double *)bz, *w = (double *)wz;
    for (int i = 0; i < n; i++) {
        double sr = b[2 * pl->perm[i]], si = b[2 * pl->perm[i] + 1];
        for (int e = rp[i]; e < dp[i]; e++) {
            double ar = a[2 * e], ai = a[2 * e + 1], xr = w[2 * ci[e]], xi = w[2 * ci[e] + 1];
            sr -= ar * xr - ai * xi;
            si -= ar * xi + ai * xr;
        }
        w[2 * i] = sr;
        w[2 * i + 1] = si;
    }
    for (int i = n - 1; i >= 0; i--) {
        double sr = w[2 * i], si = w[2 * i + 1];
        for (int e = dp[i] + 1; e < rp[i + 1]; e++) {
            double ar = a[2 * e], ai = a[2 * e + 1], xr = w[2 * ci[e]], xi = w[2 * ci[e] + 1];
            sr -= ar * xr - ai * xi;
            si -= ar * xi + ai * xr;
        }
        double dr = a[2 * dp[i]], di = a[2 * dp[i] + 1];  /* the reciprocal pivot */
        w[2 * i] = sr * dr - si * di;
        w[2 * i + 1] = sr * di + si * dr;
    }
    for (int i = 0; i < n; i++) {
        b[2 * pl->perm[i]] = w[2 * i];
        b[2 * pl->perm[i] + 1] = w[2 * i + 1];
    }
}

/* ---- the integrators' linear solver ------------------------------------------------------ */

int bgc_linsys_init(bgc_linsys *ls, const bgc_model *m, int complex_too)
{
    memset(ls, 0, sizeof *ls);
    int n = m->n;
    ls->n = n; ls->nnz = m->nnz; ls->row = m->jac_row; ls->col = m->jac_col;
    ls->plan = (m->lu && m->lu->n == n && m->lu->nnz_jac == m->nnz) ? m->lu : NULL;
    size_t nn = (size_t)n * n;
    /* the dense arrays are allocated lazily on a sparse plan's first fallback */
    if (!ls->plan) {
        ls->ad = malloc(nn * sizeof(double));
        if (complex_too) ls->adz = malloc(nn * sizeof(double complex));
    } else {
        ls->a = malloc((size_t)ls->plan->nnz_lu * sizeof(double));
        if (complex_too) ls->az = malloc((size_t)ls->plan->nnz_lu * sizeof(double complex));
    }
    ls->piv = malloc((size_t)(n + 1) * sizeof(int));
    ls->pivz = malloc((size_t)(n + 1) * sizeof(int));
    ls->w = malloc((size_t)(n + 1) * sizeof(double));
    ls->wz = malloc((size_t)(n + 1) * sizeof(double complex));
    if (!ls->piv || !ls->pivz || !ls->w || !ls->wz) return -1;
    if (!ls->plan && (!ls->ad || (complex_too && !ls->adz))) return -1;
    if (ls->plan && (!ls->a || (complex_too && !ls->az))) return -1;
    return 0;
}

void bgc_linsys_free(bgc_linsys *ls)
{
    free(ls->a); free(ls->ad); free(ls->az); free(ls->adz);
    free(ls->piv); free(ls->pivz); free(ls->w); free(ls->wz);
    memset(ls, 0, sizeof *ls);
}

static int dense_factor(bgc_linsys *ls, double c, const double *jv)
{
    int n = ls->n;
    if (!ls->ad && !(ls->ad = malloc((size_t)n * n * sizeof(double)))) return -1;
    double *a = ls->ad;
    memset(a, 0, (size_t)n * n * sizeof(double));
    for (int e = 0; e < ls->nnz; e++) a[(size_t)ls->row[e] * n + ls->col[e]] -= jv[e];
    for (int i = 0; i < n; i++) a[(size_t)i * n + i] += c;
    ls->use_dense = 1;
    return bgc_dense_lu(n, a, ls->piv);
}

int bgc_linsys_factor(bgc_linsys *ls, double c, const double *jv)
{
    const struct bgc_lu_plan *pl = ls->plan;
    if (!pl) return dense_factor(ls, c, jv);
    double *a = ls->a;
    memset(a, 0, (size_t)pl->nnz_lu * sizeof(double));
    for (int e = 0; e < ls->nnz; e++) a[pl->jac_pos[e]] -= jv[e];
    for (int i = 0; i < pl->n; i++) a[pl->diag_pos[i]] += c;
    ls->use_dense = 0;
    if (bgc_sparse_lu(pl, a) == 0) return 0;
    ls->fallbacks++;
    return dense_factor(ls, c, jv);
}

void bgc_linsys_solve(bgc_linsys *ls, double *b)
{
    if (ls->use_dense) bgc_dense_solve(ls->n, ls->ad, ls->piv, b);
    else bgc_sparse_solve(ls->plan, ls->a, b, ls->w);
}

static int dense_factor_z(bgc_linsys *ls, double complex c, const double *jv)
{
    int n = ls->n;
    if (!ls->adz && !(ls->adz = malloc((size_t)n * n * sizeof(double complex)))) return -1;
    double complex *a = ls->adz;
    for (size_t i = 0; i < (size_t)n * n; i++) a[i] = 0.0;
    for (int e = 0; e < ls->nnz; e++) a[(size_t)ls->row[e] * n + ls->col[e]] -= jv[e];
    for (int i = 0; i < n; i++) a[(size_t)i * n + i] += c;
    ls->use_dense_z = 1;
    return bgc_dense_lu_z(n, a, ls->pivz);
}

int bgc_linsys_factor_z(bgc_linsys *ls, double complex c, const double *jv)
{
    const struct bgc_lu_plan *pl = ls->plan;
    if (!pl) return dense_factor_z(ls, c, jv);
    double complex *a = ls->az;
    for (int e = 0; e < pl->nnz_lu; e++) a[e] = 0.0;
    for (int e = 0; e < ls->nnz; e++) a[pl->jac_pos[e]] -= jv[e];
    for (int i = 0; i < pl->n; i++) a[pl->diag_pos[i]] += c;
    ls->use_dense_z = 0;
    if (bgc_sparse_lu_z(pl, a) == 0) return 0;
    ls->fallbacks++;
    return dense_factor_z(ls, c, jv);
}

void bgc_linsys_solve_z(bgc_linsys *ls, double complex *b)
{
    if (ls->use_dense_z) bgc_dense_solve_z(ls->n, ls->adz, ls->pivz, b);
    else bgc_sparse_solve_z(ls->plan, ls->az, b, ls->wz);
}

int bgc_linsys_solve_once(const bgc_model *m, double c, const double *jv, double *b,
                          long *fallbacks)
{
    bgc_linsys ls;
    int s = bgc_linsys_init(&ls, m, 0);
    if (!s) s = bgc_linsys_factor(&ls, c, jv);
    if (!s) bgc_linsys_solve(&ls, b);
    if (fallbacks) *fallbacks = ls.fallbacks;
    bgc_linsys_free(&ls);
    return s;
}

int bgc_linsys_solve_once_z(const bgc_model *m, double complex c, const double *jv,
                            double complex *b, long *fallbacks)
{
    bgc_linsys ls;
    int s = bgc_linsys_init(&ls, m, 1);
    if (!s) s = bgc_linsys_factor_z(&ls, c, jv);
    if (!s) bgc_linsys_solve_z(&ls, b);
    if (fallbacks) *fallbacks = ls.fallbacks;
    bgc_linsys_free(&ls);
    return s;
}
