/* bgc runtime internals shared by the driver (bgc_runtime.c) and the integrators. */
#ifndef BGC_INTERNAL_H
#define BGC_INTERNAL_H

#include <complex.h>
#include "bgc_runtime.h"

/* ---- complex LU (Radau's second system) ---------------------------------------------------- */
int bgc_dense_lu_z(int n, double complex *a, int *piv);
void bgc_dense_solve_z(int n, const double complex *lu, const int *piv, double complex *b);
int bgc_sparse_lu_z(const struct bgc_lu_plan *pl, double complex *a);
void bgc_sparse_solve_z(const struct bgc_lu_plan *pl, const double complex *a,
                        double complex *b, double complex *w);


/* The linear solver an integrator uses for (c I - J): sparse along the model's plan when it
 * has one (falling back to dense partial pivoting for a step whose pivot is too small), else
 * dense. Internal, but declared here for the integrator files. */
typedef struct {
    int n, nnz; const int *row, *col; const struct bgc_lu_plan *plan;
    int use_dense, use_dense_z;   /* the current factorisation is dense (no plan, fallback) */
    double *a; int *piv;          /* sparse nnz_lu values, or NULL without a plan */
    double *ad;                   /* dense n*n (fallback or no plan) */
    double complex *az, *adz; int *pivz;
    double *w; double complex *wz;
    long fallbacks;
} bgc_linsys;
int bgc_linsys_init(bgc_linsys *ls, const bgc_model *m, int complex_too);
void bgc_linsys_free(bgc_linsys *ls);
/* factor c*I - J, J given by values jv on the model's pattern; 0 ok, nonzero singular */
int bgc_linsys_factor(bgc_linsys *ls, double c, const double *jv);
void bgc_linsys_solve(bgc_linsys *ls, double *b);
int bgc_linsys_factor_z(bgc_linsys *ls, double complex c, const double *jv);
void bgc_linsys_solve_z(bgc_linsys *ls, double complex *b);
/* one factorisation of c*I - J and one solve of b in place, as an integrator does them (for
 * tests); fallbacks: how many sparse factorisations fell back to the dense LU */
int bgc_linsys_solve_once(const bgc_model *m, double c, const double *jv, double *b,
                          long *fallbacks);
int bgc_linsys_solve_once_z(const bgc_model *m, double complex c, const double *jv,
                            double complex *b, long *fallbacks);


#define BGC_REJECT (-1) /* a stage state is not finite: the step is retried smaller */

typedef void (*bgc_interp_fn)(void *data, double t, double *out);

typedef struct {
    const bgc_model *m;
    const double *p;
    const bgc_options *opt;
    bgc_stats *st;
    bgc_stats_ext *xs;  /* never NULL inside (a local one when the caller gives none) */
    double rtol;        /* the method's (floored) rtol */
    double max_step;    /* > 0, inf when none */
    double deadline;    /* monotonic seconds, or inf */
    double lo, hi;      /* the segment's one-sided time window [a, nextafter(c, a)] */
    double *y_out;      /* n_out x n */
    int k_out;          /* next output row */
    /* the last non-finite rhs value of a trial stage (it rejected the step): reported if the
     * step then shrinks below its minimum; pend_index < 0: none since the last accepted step */
    int pend_index; double pend_t, pend_v;
    double *ws;         /* the model's per-instance workspace (m->nws doubles), or NULL */
    /* events (bgc_events.c): sides of zero, guard values, scratch states, recent event times */
    double *ev_mem, *ev_side, *ev_g, *ev_g2, *ev_xa, *ev_xb, *ev_recent;
    int ev_count, ev_max;
    double ev_window, t_restart;
} bgc_ctx;

/* rhs at the one-sided time; counts; 0, BGC_REJECT (x not finite), BGC_ERR_NONFINITE or
 * BGC_ERR_MODEL (st filled) */
int bgc_call_rhs(bgc_ctx *c, double t, const double *x, double *dx);
/* the same at a trial stage: a non-finite value rejects the step (BGC_REJECT) and is kept as
 * pending; bgc_step_too_small reports it when the step cannot shrink further */
int bgc_call_rhs_trial(bgc_ctx *c, double t, const double *x, double *dx);
int bgc_step_too_small(bgc_ctx *c, double t);
int bgc_call_jac(bgc_ctx *c, double t, const double *x, double *jv);
double bgc_atol(const bgc_ctx *c, int i);
/* rms of e_i / (atol_i + rtol * max(|y_i|, |z_i|)) (z may be NULL) */
double bgc_err_norm(const bgc_ctx *c, const double *e, const double *y, const double *z);
/* Hairer's starting step for a method whose error estimate has the given order */
int bgc_initial_step(bgc_ctx *c, double t, double t_end, const double *y, const double *f,
                     int order, double *h, double *work);
/* after an accepted step to t_new: write output rows for times in (t_old, t_new] */
void bgc_outputs(bgc_ctx *c, double t_new, const double *y_new, bgc_interp_fn f, void *data);
int bgc_out_of_time(bgc_ctx *c, double t);  /* wall-time check; fills st when exceeded */
/* before a step attempt of size *h_abs at t: the step can still shrink, max_steps and the
 * wall time are kept (else the status, st filled); counts the attempt, and sets *t_new to the
 * step's end (b at the latest) and *h_abs to the size it really spans */
int bgc_attempt(bgc_ctx *c, double t, double b, double *h_abs, double *t_new);
int bgc_fail(bgc_ctx *c, int status, double t, const char *fmt, ...);
double bgc_min_step(double t);

/* events: a step ended at an event; the state after it is in y, its time in c->t_restart */
#define BGC_EVENT 100
int bgc_events_init(bgc_ctx *c, double t, const double *y);
int bgc_events_restart(bgc_ctx *c, double t, const double *y);
int bgc_events_next_time(bgc_ctx *c, double t, const double *y, double b, int first,
                         double *end, int *due);
int bgc_events_fire_timed(bgc_ctx *c, double t, double *y);
/* after an accepted step from t to t_new (y: the state at t_new, f: the step's interpolant):
 * the output rows, and the events: 0, BGC_EVENT (y and c->t_restart updated) or a failure */
int bgc_step_end(bgc_ctx *c, double t, double t_new, double *y, bgc_interp_fn f, void *data);

int bgc_rodas4_segment(bgc_ctx *c, double a, double b, double *y);
int bgc_radau5_segment(bgc_ctx *c, double a, double b, double *y);
int bgc_dop853_segment(bgc_ctx *c, double a, double b, double *y);

#endif
