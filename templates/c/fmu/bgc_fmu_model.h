/* bgc FMU: what the generated model file (bgc_fmu_model.c) provides to the FMI 2.0 glue
 * (bgc_fmi2.c). Everything here is constant data and reentrant functions: an instance keeps
 * all its mutable state in its own memory.
 *
 * Value references (all fmi2Real):
 *   [0, n)                      states x
 *   [n, 2n)                     their derivatives dx
 *   [2n, 2n+np)                 parameters (flat: matrix entries row by row)
 *   [2n+np, 2n+np+nu)           inputs (flat)
 *   [2n+np+nu, 2n+np+nu+nout)   outputs (flat)
 *
 * The parameter vector the model functions take (length np_all = np + nd + 2 nu):
 *   p[0, np)          parameters
 *   p[np, np+nd)      derived parameters (bgcf_desc.derived fills them)
 *   p[np+nd, +nu)     input values
 *   p[np+nd+nu, +nu)  1.0 where the input follows the model's default signal (not set through
 *                     fmi2SetReal), 0.0 where it holds the value set
 */
#ifndef BGC_FMU_MODEL_H
#define BGC_FMU_MODEL_H

#include "bgc_runtime.h"

typedef struct {
    int n, np, nd, nu, nout, nnz, np_all;
    const bgc_model *model;  /* rhs and Jacobian on the pattern (p of length np_all) */
    int (*outputs)(double t, const double *x, const double *p, double *y);
    int (*init)(const double *p, double *x0);
    void (*derived)(double *p);                               /* p[np..np+nd) from p[0..np) */
    void (*input_defaults)(double t, const double *p, double *u);   /* the default signals */
    const char *guid;
    const char *model_identifier;
    const double *param_start;        /* np */
    const unsigned char *param_tunable;  /* np: 1 tunable, 0 fixed */
    const double *input_start;        /* nu: the default at the start time */
    int method;                       /* BGC_RODAS4 or BGC_RADAU5 */
    double rtol, atol, max_step;
    const double *breaks; int n_breaks;   /* the scene's breakpoints (time events), sorted */
    /* a hybrid model's events (0 and NULL without): the guards g (nev values: the event
     * indicators), each event's direction (+1 rising, -1 falling, 0 either) and its resets
     * (x_new: the state just after event k, from x just before; all n values) */
    int nev;
    int (*guards)(double t, const double *x, const double *p, double *g);
    int (*reset)(int k, double t, const double *x, const double *p, double *x_new);
    const int *ev_dir;
    /* closed kinematic loops (0 and NULL without): ncons constraint components; cons gives
     * their position residuals, velocity residuals (ncons each) and the kinetic energy;
     * cons_names the constraint (its source element) of each component */
    int ncons;
    int (*cons)(double t, const double *x, const double *p, double *r);
    const char *const *cons_names;
} bgcf_desc;

extern const bgcf_desc bgcf_model_desc;

#endif
