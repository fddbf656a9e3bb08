/* bgc runtime driver: argument checks, segments between breakpoints (one-sided inputs),
 * output rows, model calls with non-finite detection, wall time, batches over threads. */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "bgc_internal.h"

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int bgc_have_openmp(void)
{
#ifdef _OPENMP
    return 1;
#else
    return 0;
#endif
}

int bgc_fail(bgc_ctx *c, int status, double t, const char *fmt, ...)
{
    bgc_stats *st = c->st;
    st->status = status;
    st->t_fail = t;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(st->message, sizeof st->message, fmt, ap);
    va_end(ap);
    return status;
}

static const char *method_name(int method)
{
    return method == BGC_RADAU5 ? "Radau5" : method == BGC_DOP853 ? "DOP853" : "Rodas4";
}

double bgc_min_step(double t) { return 10.0 * fabs(nextafter(t, INFINITY) - t); }

static int nonfinite_rhs(bgc_ctx *c, int i, double v, double t)
{
    c->st->bad_index = i;
    c->st->bad_where = 0;
    return bgc_fail(c, BGC_ERR_NONFINITE, t, "%s: the right-hand side of state %d is not "
                    "finite (%g) at t = %.17g", method_name(c->opt->method), i, v, t);
}

static int call_rhs(bgc_ctx *c, double t, const double *x, double *dx, int trial)
{
    const int n = c->m->n;
    for (int i = 0; i < n; i++)
        if (!isfinite(x[i])) return BGC_REJECT;
    double tm = t < c->lo ? c->lo : (t > c->hi ? c->hi : t);
    c->st->nfev++;
    int r = c->m->rhs_ws ? c->m->rhs_ws(tm, x, c->p, dx, c->ws) : c->m->rhs(tm, x, c->p, dx);
    if (r) {
        c->st->bad_index = r; c->st->bad_where = 2;
        return bgc_fail(c, BGC_ERR_MODEL, t, "%s: the model's right-hand side failed (code %d) "
                        "at t = %.17g", method_name(c->opt->method), r, t);
    }
    for (int i = 0; i < n; i++)
        if (!isfinite(dx[i])) {
            if (!trial) return nonfinite_rhs(c, i, dx[i], t);
            c->pend_index = i; c->pend_t = t; c->pend_v = dx[i];
            return BGC_REJECT;
        }
    return 0;
}

int bgc_call_rhs(bgc_ctx *c, double t, const double *x, double *dx) { return call_rhs(c, t, x, dx, 0); }
int bgc_call_rhs_trial(bgc_ctx *c, double t, const double *x, double *dx) { return call_rhs(c, t, x, dx, 1); }

int bgc_step_too_small(bgc_ctx *c, double t)
{
    if (c->pend_index >= 0) return nonfinite_rhs(c, c->pend_index, c->pend_v, c->pend_t);
    return bgc_fail(c, BGC_ERR_STEP_TOO_SMALL, t, "%s failed at t = %.17g: the step size fell "
                    "below its minimum (10 ulp of t)", method_name(c->opt->method), t);
}

int bgc_call_jac(bgc_ctx *c, double t, const double *x, double *jv)
{
    double tm = t < c->lo ? c->lo : (t > c->hi ? c->hi : t);
    c->st->njev++;
    int r = c->m->jac_ws ? c->m->jac_ws(tm, x, c->p, jv, c->ws) : c->m->jac(tm, x, c->p, jv);
    if (r) {
        c->st->bad_index = r; c->st->bad_where = 2;
        return bgc_fail(c, BGC_ERR_MODEL, t, "%s: the model's Jacobian failed (code %d) at "
                        "t = %.17g", method_name(c->opt->method), r, t);
    }
    for (int e = 0; e < c->m->nnz; e++)
        if (!isfinite(jv[e])) {
            c->st->bad_index = c->m->jac_row[e];
            c->xs->bad_entry = e;
            c->st->bad_where = 1;
            return bgc_fail(c, BGC_ERR_NONFINITE, t, "%s: the Jacobian entry d(state %d)/d(state "
                            "%d) is not finite (%g) at t = %.17g", method_name(c->opt->method),
                            c->m->jac_row[e], c->m->jac_col[e], jv[e], t);
        }
    return 0;
}

double bgc_atol(const bgc_ctx *c, int i) { return c->opt->atol_len == 1 ? c->opt->atol[0] : c->opt->atol[i]; }

double bgc_err_norm(const bgc_ctx *c, const double *e, const double *y, const double *z)
{
    const int n = c->m->n;
    double s = 0.0;
    for (int i = 0; i < n; i++) {
        double a = fabs(y[i]);
        if (z && fabs(z[i]) > a) a = fabs(z[i]);
        double r = e[i] / (bgc_atol(c, i) + c->rtol * a);
        s += r * r;
    }
    return n ? sqrt(s / n) : 0.0;
}

static double rms_scaled(const bgc_ctx *c, const double *v, const double *y)
{
    return bgc_err_norm(c, v, y, NULL);
}

int bgc_initial_step(bgc_ctx *c, double t, double t_end, const double *y, const double *f,
                     int order, double *h, double *work)
{
    const int n = c->m->n;
    if (n == 0 || t_end == t) { *h = INFINITY; return 0; }
    double d0 = rms_scaled(c, y, y), d1 = rms_scaled(c, f, y);
    double h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
    if (h0 > t_end - t) h0 = t_end - t;
    double *y1 = work, *f1 = work + n;
    for (int i = 0; i < n; i++) y1[i] = y[i] + h0 * f[i];
    int s = bgc_call_rhs_trial(c, t + h0, y1, f1);
    if (s == BGC_REJECT) { *h = h0 * 1e-3; return 0; }
    if (s) return s;
    for (int i = 0; i < n; i++) f1[i] -= f[i];
    double d2 = rms_scaled(c, f1, y) / h0;
    double dm = d1 > d2 ? d1 : d2;
    double h1 = dm <= 1e-15 ? fmax(1e-6, h0 * 1e-3) : pow(0.01 / dm, 1.0 / (order + 1));
    double hh = 100 * h0;
    if (h1 < hh) hh = h1;
    if (c->max_step < hh) hh = c->max_step;
    *h = hh;
    return 0;
}

void bgc_outputs(bgc_ctx *c, double t_new, const double *y_new, bgc_interp_fn f, void *data)
{
    const int n = c->m->n;
    while (c->k_out < c->opt->n_out && c->opt->t_out[c->k_out] <= t_new) {
        double *row = c->y_out + (size_t)c->k_out * n;
        double to = c->opt->t_out[c->k_out];
        if (to == t_new) memcpy(row, y_new, (size_t)n * sizeof(double));
        else f(data, to, row);
        c->k_out++;
    }
    c->xs->n_done = c->k_out;
}

int bgc_out_of_time(bgc_ctx *c, double t)
{
    if (c->deadline < INFINITY && now_s() > c->deadline)
        return bgc_fail(c, BGC_ERR_WALL, t, "%s stopped at t = %.17g: the wall time exceeded "
                        "max_wall = %g s", method_name(c->opt->method), t, c->opt->max_wall);
    return 0;
}

int bgc_attempt(bgc_ctx *c, double t, double b, double *h_abs, double *t_new)
{
    if (*h_abs < bgc_min_step(t)) return bgc_step_too_small(c, t);
    if (c->opt->max_steps > 0 && c->st->nsteps >= c->opt->max_steps)
        return bgc_fail(c, BGC_ERR_MAX_STEPS, t, "%s stopped at t = %.17g: max_steps = %ld "
                        "step attempts", method_name(c->opt->method), t, c->opt->max_steps);
    int status = bgc_out_of_time(c, t);
    if (status) return status;
    c->st->nsteps++;
    *t_new = t + *h_abs;  /* the step ends at b at the latest, and is what it really spans */
    if (*t_new > b) *t_new = b;
    *h_abs = *t_new - t;
    return 0;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int bgc_integrate(const bgc_model *m, const double *p, double t0, double t1, const double *x0,
                  const bgc_options *opt, double *y_out, bgc_stats *st)
{
    return bgc_integrate_ex(m, p, t0, t1, x0, opt, y_out, st, NULL);
}

static int method_segment(bgc_ctx *c, double a, double b, double *y)
{
    return c->opt->method == BGC_RADAU5 ? bgc_radau5_segment(c, a, b, y)
           : c->opt->method == BGC_DOP853 ? bgc_dop853_segment(c, a, b, y)
           : bgc_rodas4_segment(c, a, b, y);
}

/* one segment; a hybrid model's integrator restarts (a fresh Jacobian and LU) after each
 * event inside it (bgc_events.c), and stops exactly at each time event (a breakpoint: the
 * integrator's end is the event's time) to fire it there. first: the run's first segment,
 * where a time event at its very start fires too. */
static int run_segment(bgc_ctx *c, double a, double b, double *y, int first)
{
    const int timed = c->m->nev > 0 && c->m->ev_timed;
    double t = a;
    while (t < b) {
        double end = b;
        int due = 0, status;
        if (timed) {
            if ((status = bgc_events_next_time(c, t, y, b, first, &end, &due))) return status;
            if (due && end == t) {  /* at the run's very start */
                if ((status = bgc_events_fire_timed(c, t, y))) return status;
                if ((status = bgc_events_restart(c, t, y))) return status;
                if ((status = bgc_events_next_time(c, t, y, b, 0, &end, &due))) return status;
            }
        }
        first = 0;
        status = method_segment(c, t, end, y);
        if (status == BGC_EVENT) {
            t = c->t_restart;
            if (due && t == end && (status = bgc_events_fire_timed(c, t, y))) return status;
            if (t < b && (status = bgc_events_restart(c, t, y))) return status;
            continue;
        }
        if (status) return status;
        t = end;
        if (due) {
            if ((status = bgc_events_fire_timed(c, t, y))) return status;
            if (t < b && (status = bgc_events_restart(c, t, y))) return status;
        }
    }
    return 0;
}

int bgc_integrate_ex(const bgc_model *m, const double *p, double t0, double t1,
                     const double *x0, const bgc_options *opt, double *y_out, bgc_stats *st,
                     bgc_stats_ext *ext)
{
    if (!st) return BGC_ERR_ARGS;
    bgc_stats_ext local;
    if (!ext) ext = &local;
    memset(st, 0, sizeof *st);
    memset(ext, 0, sizeof *ext);
    st->bad_index = -1;
    ext->bad_entry = -1;
    st->t_fail = NAN;
    ext->t_last = t0;
    bgc_ctx c;
    memset(&c, 0, sizeof c);
    c.m = m; c.p = p; c.opt = opt; c.st = st; c.xs = ext; c.y_out = y_out;
    c.lo = -INFINITY; c.hi = INFINITY;
    c.pend_index = -1;
    /* argument checks */
    const char *bad = NULL;
    if (!m || !opt || !st || !x0 || m->n < 0 || m->nnz < 0 || !m->rhs || !m->jac)
        bad = "missing model, options or state";
    else if (m->nev > 0 && (!m->guards || !m->reset || !m->ev_dir))
        bad = "events without their functions";
    else if (opt->method != BGC_RODAS4 && opt->method != BGC_RADAU5 && opt->method != BGC_DOP853)
        bad = "unknown method";
    else if (!(opt->rtol > 0) || !isfinite(opt->rtol)) bad = "rtol must be positive";
    else if (!opt->atol || (opt->atol_len != 1 && opt->atol_len != m->n)) bad = "atol: give 1 or n values";
    else if (!(t1 >= t0) || !isfinite(t0) || !isfinite(t1)) bad = "the span must have t1 >= t0 (finite)";
    else if (opt->n_out < 0 || (opt->n_out > 0 && (!opt->t_out || !y_out))) bad = "output times without an output array";
    else if (opt->n_breaks < 0 || (opt->n_breaks > 0 && !opt->breaks)) bad = "breakpoints missing";
    if (!bad && opt) {
        for (int i = 0; i < opt->atol_len; i++)
            if (!(opt->atol[i] >= 0) || !isfinite(opt->atol[i])) bad = "atol must be >= 0 and finite";
        for (int k = 0; k < opt->n_out; k++)
            if (!(opt->t_out[k] >= t0 && opt->t_out[k] <= t1) || (k && !(opt->t_out[k] > opt->t_out[k - 1])))
                bad = "output times must be strictly increasing and within [t0, t1]";
        for (int i = 0; i < m->n; i++)
            if (!isfinite(x0[i])) bad = "the initial state is not finite";
    }
    for (int k = 0; opt && y_out && k < opt->n_out * (m ? m->n : 0); k++) y_out[k] = NAN;
    if (bad) {
        st->status = BGC_ERR_ARGS;
        snprintf(st->message, sizeof st->message, "bgc_integrate: %s", bad);
        return BGC_ERR_ARGS;
    }
    const int n = m->n;
    double eps = 2.220446049250313e-16;
    c.rtol = opt->rtol > 100 * eps ? opt->rtol : 100 * eps;
    c.max_step = opt->max_step > 0 ? opt->max_step : INFINITY;
    c.deadline = opt->max_wall > 0 ? now_s() + opt->max_wall : INFINITY;
    /* breakpoints strictly inside the span, sorted, unique */
    double *cuts = malloc(((size_t)opt->n_breaks + 2) * sizeof(double));
    double *y = malloc(((size_t)n + 1) * sizeof(double));
    c.ws = m->nws > 0 ? calloc((size_t)m->nws, sizeof(double)) : NULL;
    if (!cuts || !y || (m->nws > 0 && !c.ws)) {
        free(cuts); free(y); free(c.ws);
        return bgc_fail(&c, BGC_ERR_ARGS, t0, "bgc_integrate: out of memory");
    }
    int nc = 0;
    cuts[nc++] = t0;
    for (int k = 0; k < opt->n_breaks; k++)
        if (opt->breaks[k] > t0 && opt->breaks[k] < t1) cuts[nc++] = opt->breaks[k];
    qsort(cuts + 1, (size_t)(nc - 1), sizeof(double), cmp_double);
    int u = 1;
    for (int k = 1; k < nc; k++)
        if (cuts[k] != cuts[u - 1]) cuts[u++] = cuts[k];
    nc = u;
    cuts[nc++] = t1;
    memcpy(y, x0, (size_t)n * sizeof(double));
    /* output times at t0 get x0 */
    while (c.k_out < opt->n_out && opt->t_out[c.k_out] <= t0) {
        memcpy(y_out + (size_t)c.k_out * n, x0, (size_t)n * sizeof(double));
        c.k_out++;
    }
    ext->n_done = c.k_out;
    int status = 0;
    if (m->nev > 0) {
        c.ev_window = 1e-6 * (t1 - t0);
        status = bgc_events_init(&c, t0, y);
    }
    for (int s = 0; s + 1 < nc && !status; s++) {
        double a = cuts[s], b = cuts[s + 1];
        if (a == b) continue;
        c.lo = a;
        c.hi = nextafter(b, a);
        status = run_segment(&c, a, b, y, s == 0);
    }
    free(cuts); free(y); free(c.ws); free(c.ev_mem);
    if (status == BGC_REJECT)  /* not expected: accepted states are finite */
        status = bgc_fail(&c, BGC_ERR_STEP_TOO_SMALL, ext->t_last, "%s failed at t = %.17g: "
                          "the state is not finite", method_name(opt->method), ext->t_last);
    st->status = status;
    if (!status) {
        ext->t_last = t1;
        snprintf(st->message, sizeof st->message, "%s: reached t = %.17g", method_name(opt->method), t1);
    }
    return status;
}

int bgc_integrate_batch(const bgc_model *m, int nb, const double *P, const double *X0,
                        double t0, double t1, const bgc_options *opt, double *Y_out,
                        bgc_stats *st, int nthreads)
{
    if (!m || !opt || !st || nb < 0 || (nb > 0 && !X0)) return BGC_ERR_ARGS;
    const size_t rows = opt->n_out > 0 ? (size_t)opt->n_out * m->n : 0;
#ifdef _OPENMP
    if (nthreads <= 0) nthreads = omp_get_max_threads();
#pragma omp parallel for schedule(dynamic, 1) num_threads(nthreads)
#else
    (void)nthreads;
#endif
    for (int k = 0; k < nb; k++) {
        bgc_options o = *opt;  /* each instance its own event log */
        if (o.ev_log) o.ev_log += (size_t)k * (size_t)o.ev_cap * (2 * (size_t)m->n + 2);
        if (o.ev_count) o.ev_count += k;
        bgc_integrate(m, P ? P + (size_t)k * m->np : NULL, t0, t1, X0 + (size_t)k * m->n, &o,
                      Y_out ? Y_out + (size_t)k * rows : NULL, st + k);
    }
    for (int k = 0; k < nb; k++)
        if (st[k].status) return st[k].status;
    return BGC_OK;
}
