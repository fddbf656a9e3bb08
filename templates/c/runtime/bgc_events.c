/* bgc runtime: events of hybrid models (bgc_model.nev > 0), per instance.
 *
 * After each accepted step the integrators call bgc_step_end. It evaluates the guards at the
 * step's end and compares each with the side of zero it was last on; a guard that left its side
 * in its event's direction is located on the step's dense output (Radau's collocation
 * polynomial, Rodas4's interpolant) by the Illinois variant of regula falsi, to a bracket of a
 * few ulp of t. The earliest such time ends the step there: the output rows up to it are
 * written from the dense output, the events that fire there get their resets (in declaration
 * order), and the integrator returns BGC_EVENT; the driver restarts it (a fresh Jacobian and
 * LU) from the state just after. The same rules as the numpy runtime (templates/numpy/events.py).
 * A time event (ev_timed) is not searched for: bgc_events_next_time gives the driver the next
 * one's time (t - its guard) as the integrator's end, and bgc_events_fire_timed fires it there. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "bgc_internal.h"

#define EV_ITER 200  /* root-finder iterations per event */

/* the guards at (t, x), t held in the segment's one-sided window; 0 or a failure status */
static int guards(bgc_ctx *c, double t, const double *x, double *g)
{
    const bgc_model *m = c->m;
    double tm = t < c->lo ? c->lo : (t > c->hi ? c->hi : t);
    int r = m->guards(tm, x, c->p, g);
    if (r) {
        c->st->bad_index = r; c->st->bad_where = 2;
        return bgc_fail(c, BGC_ERR_MODEL, t, "an event's condition failed (code %d) at "
                        "t = %.17g", r, t);
    }
    for (int k = 0; k < m->nev; k++)
        if (!isfinite(g[k])) {
            c->st->bad_index = k; c->st->bad_where = 3;
            return bgc_fail(c, BGC_ERR_NONFINITE, t, "event %d: its condition is not finite "
                            "(%g) at t = %.17g", k, g[k], t);
        }
    return 0;
}

int bgc_events_init(bgc_ctx *c, double t, const double *y)
{
    const int n = c->m->n, nev = c->m->nev;
    const bgc_options *o = c->opt;
    c->ev_max = o->max_events > 0 ? o->max_events : 20;
    /* side, g, g2 (nev each); xa, xb (n each); the recent event times (ev_max + 1) */
    c->ev_mem = malloc(sizeof(double) * (3 * (size_t)nev + 2 * (size_t)n + (size_t)c->ev_max + 1));
    if (!c->ev_mem) return bgc_fail(c, BGC_ERR_ARGS, t, "bgc_integrate: out of memory");
    c->ev_side = c->ev_mem; c->ev_g = c->ev_side + nev; c->ev_g2 = c->ev_g + nev;
    c->ev_xa = c->ev_g2 + nev; c->ev_xb = c->ev_xa + n; c->ev_recent = c->ev_xb + n;
    c->ev_count = 0;
    /* a guard that starts at zero counts as before its event (a rising one as negative) */
    for (int k = 0; k < nev; k++) c->ev_side[k] = -(double)c->m->ev_dir[k];
    return bgc_events_restart(c, t, y);
}

int bgc_events_restart(bgc_ctx *c, double t, const double *y)
{
    int status = guards(c, t, y, c->ev_g);
    if (status) return status;
    for (int k = 0; k < c->m->nev; k++)
        if (c->ev_g[k] != 0.0) c->ev_side[k] = c->ev_g[k] > 0 ? 1.0 : -1.0;
    return 0;
}

/* where guard k leaves side s in (ta, tb]: *tb_out the time just past the crossing */
static int locate(bgc_ctx *c, int k, double s, double ta, double tb, bgc_interp_fn f,
                  void *data, double *tb_out)
{
    double *x = c->ev_xa, *g = c->ev_g2;
    int status;
    if ((status = guards(c, ta, (f(data, ta, x), x), g))) return status;
    double ga = fmax(s * g[k], 2.2250738585072014e-308);
    if ((status = guards(c, tb, (f(data, tb, x), x), g))) return status;
    double gb = s * g[k], width = fabs(tb - ta);
    int stale = 0;
    if (gb > 0) { *tb_out = tb; return 0; }  /* the dense output's end disagrees: the end */
    for (int it = 0; it < EV_ITER && gb != 0.0; it++) {
        if (fabs(tb - ta) <= 8.9e-16 * fmax(1.0, fmax(fabs(ta), fabs(tb)))) break;
        double tm = ta + (tb - ta) * (ga / (ga - gb));
        if (it % 3 == 2) {
            if (fabs(tb - ta) > width / 2) tm = 0.5 * (ta + tb);
            width = fabs(tb - ta);
        }
        if (!(tm > fmin(ta, tb) && tm < fmax(ta, tb))) tm = 0.5 * (ta + tb);
        f(data, tm, x);
        if ((status = guards(c, tm, x, g))) return status;
        double gm = s * g[k];
        if (gm > 0) { ta = tm; ga = gm; if (stale == 1) gb /= 2; stale = 1; }
        else { tb = tm; gb = gm; if (stale == -1) ga /= 2; stale = -1; }
    }
    *tb_out = tb;
    return 0;
}

/* event k fired at t: the log, the count and the Zeno guard */
static int record(bgc_ctx *c, int k, double t, const double *before, const double *after)
{
    const int n = c->m->n;
    const bgc_options *o = c->opt;
    if (o->ev_log && c->ev_count < o->ev_cap) {
        double *row = o->ev_log + (size_t)c->ev_count * (2 * (size_t)n + 2);
        row[0] = t; row[1] = k;
        memcpy(row + 2, before, sizeof(double) * (size_t)n);
        memcpy(row + 2 + n, after, sizeof(double) * (size_t)n);
    }
    c->ev_recent[c->ev_count % (c->ev_max + 1)] = t;
    c->ev_count++;
    if (o->ev_count) *o->ev_count = c->ev_count;
    if (c->ev_count > c->ev_max) {
        double oldest = c->ev_recent[c->ev_count % (c->ev_max + 1)];
        double window = o->zeno_window > 0 ? o->zeno_window : c->ev_window;
        if (t - oldest <= window) {
            c->st->bad_index = k; c->st->bad_where = 4;
            return bgc_fail(c, BGC_ERR_ZENO, t, "event %d at t = %.9g: %d events within %.3g s "
                            "(Zeno behaviour or chattering)", k, t, c->ev_max + 1, t - oldest);
        }
    }
    return 0;
}

/* event k's reset at t: y (the state before, kept in ev_xa) becomes the state after; the
 * reset reads its time clamped to the integration window; a failed or non-finite reset is an
 * error naming the event */
static int apply_reset(bgc_ctx *c, int k, double t, double *y)
{
    const bgc_model *m = c->m;
    const int n = m->n;
    memcpy(c->ev_xa, y, sizeof(double) * (size_t)n);
    double tm = t < c->lo ? c->lo : (t > c->hi ? c->hi : t);
    int r = m->reset(k, tm, c->ev_xa, c->p, y);
    if (r) {
        c->st->bad_index = r; c->st->bad_where = 2;
        return bgc_fail(c, BGC_ERR_MODEL, t, "event %d: its reset failed (code %d) at "
                        "t = %.17g", k, r, t);
    }
    for (int i = 0; i < n; i++)
        if (!isfinite(y[i]))
            return bgc_fail(c, BGC_ERR_NONFINITE, t, "event %d: its reset of state %d "
                            "is not finite at t = %.17g", k, i, t);
    return 0;
}

int bgc_step_end(bgc_ctx *c, double t, double t_new, double *y, bgc_interp_fn f, void *data)
{
    const bgc_model *m = c->m;
    const int n = m->n;
    if (m->nev <= 0) { bgc_outputs(c, t_new, y, f, data); return 0; }
    int status = guards(c, t_new, y, c->ev_g);
    if (status) return status;
    double t_stop = INFINITY;
    for (int k = 0; k < m->nev; k++) {  /* the earliest crossing */
        double s = c->ev_side[k], g = c->ev_g[k];
        if (s == 0.0 || g * s > 0 || (m->ev_timed && m->ev_timed[k])) continue;
        if (m->ev_dir[k] != 0 && m->ev_dir[k] != (int)-s) {
            if (g != 0.0) c->ev_side[k] = -s;
            continue;
        }
        double tk;
        if ((status = locate(c, k, s, t, t_new, f, data, &tk))) return status;
        if (tk < t_stop) t_stop = tk;
    }
    if (t_stop == INFINITY) { bgc_outputs(c, t_new, y, f, data); return 0; }
    double *x = c->ev_xb;  /* the state just before the events */
    if (t_stop == t_new) memcpy(x, y, sizeof(double) * (size_t)n);
    else f(data, t_stop, x);
    bgc_outputs(c, t_stop, x, f, data);
    if ((status = guards(c, t_stop, x, c->ev_g))) return status;
    memcpy(y, x, sizeof(double) * (size_t)n);
    for (int k = 0; k < m->nev; k++) {  /* every event past its zero at t_stop, in order */
        double s = c->ev_side[k];
        if (s == 0.0 || c->ev_g[k] * s > 0 || (m->ev_timed && m->ev_timed[k])) continue;
        if (m->ev_dir[k] != 0 && m->ev_dir[k] != (int)-s) continue;
        if ((status = apply_reset(c, k, t_stop, y))) return status;
        c->ev_side[k] = -s;
        if ((status = record(c, k, t_stop, c->ev_xa, y))) return status;
    }
    c->t_restart = t_stop;
    c->xs->t_last = t_stop;
    return BGC_EVENT;
}

static double timed_tol(double t, double b)
{
    return 4 * 2.220446049250313e-16 * fmax(1.0, fmax(fabs(t), fabs(b)));
}

/* the integrator's end from t: the earliest time event in (t, b] (first: [t, b]), else b;
 * *due: whether a time event is at *end */
int bgc_events_next_time(bgc_ctx *c, double t, const double *y, double b, int first,
                         double *end, int *due)
{
    const bgc_model *m = c->m;
    int status = guards(c, t, y, c->ev_g2);
    if (status) return status;
    double tol = timed_tol(t, b), best = INFINITY;
    for (int k = 0; k < m->nev; k++) {
        if (!m->ev_timed[k]) continue;
        double tau = t - c->ev_g2[k];
        if ((first ? tau >= t : tau > t + tol) && tau <= b && tau < best) best = tau;
    }
    *due = best < INFINITY;
    *end = !*due ? b : (b - best <= tol ? b : best);
    return 0;
}

/* the time events due at t (the integrator's end): their resets, in declaration order */
int bgc_events_fire_timed(bgc_ctx *c, double t, double *y)
{
    const bgc_model *m = c->m;
    int status = guards(c, t, y, c->ev_g2);
    if (status) return status;
    double tol = timed_tol(t, t);
    for (int k = 0; k < m->nev; k++) {
        if (!m->ev_timed[k] || fabs(c->ev_g2[k]) > tol) continue;
        if ((status = apply_reset(c, k, t, y))) return status;
        if ((status = record(c, k, t, c->ev_xa, y))) return status;
    }
    c->xs->t_last = t;
    return 0;
}
