/* bgc FMU: the FMI 2.0 interface (Model Exchange and Co-Simulation) over a generated model
 * (bgc_fmu_model.h) and bgc's C integrators (bgc_runtime.h).
 *
 * Every instance owns its memory (no mutable globals): several instances of one FMU run side
 * by side. Every entry point checks its instance pointer, the FMI state machine, value
 * references, array pointers and values (non-finite reals are refused) and answers a bad call
 * with fmi2Error (or fmi2Discard for a step the integrator could not finish), logging why
 * through the importer's logger when it gave one.
 *
 * Inputs: an input not yet set through fmi2SetReal follows the model's default signal (an
 * expression of t and the parameters); once set it holds the value set (piecewise constant
 * between communication points), until fmi2Reset. Scene breakpoints are time events in Model
 * Exchange and integrator restarts in Co-Simulation; between two of them the model sees t
 * one-sided (as bgc's own runs do).
 */
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "bgc_fmu_config.h"
#include "bgc_fmu_model.h"

#define D (&bgcf_model_desc)

enum {
    S_INSTANTIATED = 1 << 0, S_INIT = 1 << 1, S_EVENT = 1 << 2, S_CONT = 1 << 3,
    S_STEP_COMPLETE = 1 << 4, S_STEP_FAILED = 1 << 5, S_TERMINATED = 1 << 6, S_ERROR = 1 << 7
};
#define S_ANY_ME (S_INSTANTIATED | S_INIT | S_EVENT | S_CONT | S_TERMINATED | S_ERROR)
#define S_ANY_CS (S_INSTANTIATED | S_INIT | S_STEP_COMPLETE | S_STEP_FAILED | S_TERMINATED | S_ERROR)

typedef struct {
    unsigned magic;
    fmi2Type type;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment env;
    fmi2Boolean logging;
    char name[128];
    int state;
    double t, t_start, t_stop;
    int stop_defined;
    double rtol;
    double seg_end;            /* next time event (breakpoint) after the current segment */
    int dirty;                 /* dx and y need recomputing */
    int init_dirty;            /* derived parameters and x0 need recomputing (init mode) */
    int eval_failed;
    double *x, *dx, *p, *y, *jv, *xnew, *u;  /* u: the inputs' default values (scratch) */
    double *side, *g;          /* events: the side of zero each guard was last on; scratch */
} inst_t;

#define MAGIC 0xB6C2F301u

/* ---- logging -------------------------------------------------------------------------- */

static void logf_(inst_t *c, fmi2Status st, const char *cat, const char *fmt, ...)
{
    if (!c || !c->logger) return;
    if (!c->logging && st == fmi2OK) return;
    char raw[512], msg[1100];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(raw, sizeof raw, fmt, ap);
    va_end(ap);
    /* the importer may read the message as a printf format: double every '%' */
    size_t j = 0;
    for (size_t i = 0; raw[i] && j + 2 < sizeof msg; i++) {
        msg[j++] = raw[i];
        if (raw[i] == '%') msg[j++] = '%';
    }
    msg[j] = '\0';
    c->logger(c->env, c->name, st, cat, msg);
}

#define ERR(c, ...) (logf_((c), fmi2Error, "logStatusError", __VA_ARGS__), fmi2Error)

static inst_t *as_inst(fmi2Component comp)
{
    inst_t *c = (inst_t *)comp;
    if (!c || c->magic != MAGIC) return NULL;
    return c;
}

/* instance check + allowed states */
static int check(inst_t *c, int allowed, const char *fn)
{
    if (!c) return 0;
    if (!(c->state & allowed)) {
        logf_(c, fmi2Error, "logStatusError", "%s: not allowed in the instance's current state",
              fn);
        return 0;
    }
    return 1;
}

#define ENTER(comp, allowed, fn)                                                             \
    inst_t *c = as_inst(comp);                                                               \
    if (!c) return fmi2Error;                                                                \
    if (!check(c, (allowed), (fn))) return fmi2Error;

/* ---- model evaluation ----------------------------------------------------------------- */

static int U0(void) { return D->np + D->nd; }         /* input values in p */
static int M0(void) { return D->np + D->nd + D->nu; } /* input flags in p */
static int VR_P(void) { return 2 * D->n; }
static int VR_U(void) { return 2 * D->n + D->np; }
static int VR_Y(void) { return 2 * D->n + D->np + D->nu; }
static int NVR(void) { return 2 * D->n + D->np + D->nu + D->nout; }

static int all_finite(const double *v, int n, int *bad)
{
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) { if (bad) *bad = i; return 0; }
    return 1;
}

/* the time the model sees: one-sided before the next time event in continuous-time mode */
static double t_model(const inst_t *c)
{
    if ((c->state & S_CONT) && c->t >= c->seg_end) return nextafter(c->seg_end, -INFINITY);
    return c->t;
}

static double next_break(double t)
{
    for (int k = 0; k < D->n_breaks; k++)
        if (D->breaks[k] > t) return D->breaks[k];
    return INFINITY;
}

static void do_init(inst_t *c)
{
    D->derived(c->p);
    D->init(c->p, c->x);
    c->init_dirty = 0;
    c->dirty = 1;
}

/* dx and y at the current time and state; 0 on success */
static int evaluate(inst_t *c)
{
    if (c->init_dirty) do_init(c);
    if (!c->dirty) return c->eval_failed;
    double t = t_model(c);
    int bad = -1;
    c->eval_failed = 0;
    if (D->model->rhs(t, c->x, c->p, c->dx) != 0 || !all_finite(c->dx, D->n, &bad)) {
        logf_(c, fmi2Error, "logStatusError", "the derivative of state %d is not finite at "
              "t = %g", bad, c->t);
        c->eval_failed = 1;
    }
    if (D->nout && (D->outputs(t, c->x, c->p, c->y) != 0 || !all_finite(c->y, D->nout, &bad))) {
        logf_(c, fmi2Error, "logStatusError", "output %d is not finite at t = %g", bad, c->t);
        c->eval_failed = 1;
    }
    c->dirty = 0;
    return c->eval_failed;
}

/* ---- events (hybrid models) ---------------------------------------------------------------
 * The guards are the event indicators. An event with a direction is armed while its guard is
 * seen before it (falling: positive), by any evaluation, and fires in event mode when armed and
 * its guard has reached zero or passed it; it is then disarmed until its guard is seen before
 * it again. (The environment may evaluate the indicators past a crossing before it locates it:
 * that never disarms.) A guard zero where the run starts counts as before its event (as in
 * bgc's own runtimes): it fires once the guard has left zero in its direction. An event in
 * either direction keeps the side its guard had at the last event mode and fires when the
 * guard has left it. */
static int guards_now(inst_t *c)
{
    int bad = -1;
    if (D->guards(t_model(c), c->x, c->p, c->g) != 0 || !all_finite(c->g, D->nev, &bad))
        return 1;
    for (int k = 0; k < D->nev; k++)  /* arm the events whose guards are before them */
        if (D->ev_dir[k] != 0 && c->g[k] * D->ev_dir[k] < 0) c->side[k] = -D->ev_dir[k];
    return 0;
}

static int events_start(inst_t *c)
{
    if (D->nev == 0) return 0;
    for (int k = 0; k < D->nev; k++) c->side[k] = D->ev_dir[k];  /* disarmed */
    if (guards_now(c)) return 1;
    for (int k = 0; k < D->nev; k++) {
        if (D->ev_dir[k] == 0) c->side[k] = c->g[k] > 0 ? 1.0 : c->g[k] < 0 ? -1.0 : 0.0;
        /* a guard zero at the start counts as before its event, as in bgc's own runs: armed
         * at zero (half a side), it fires once it has left zero in its direction */
        else if (c->g[k] == 0.0) c->side[k] = -0.5 * D->ev_dir[k];
    }
    return 0;
}

/* the events that fire at the current time and state, their resets applied in declaration
 * order: 1 when the state changed, 0 when not, -1 when a guard or a reset is not finite */
static int events_fire(inst_t *c)
{
    if (D->nev == 0) return 0;
    if (guards_now(c)) return -1;
    int changed = 0, bad = -1;
    for (int k = 0; k < D->nev; k++) {
        int d = D->ev_dir[k];
        double s = c->side[k], g = c->g[k];
        int fire = d != 0 ? (s == -d && g * d >= 0) || (s == -0.5 * d && g * d > 0)
                          : s != 0.0 && !(g * s > 0.0);
        if (fire) {
            if (D->reset(k, t_model(c), c->x, c->p, c->xnew) != 0 ||
                    !all_finite(c->xnew, D->n, &bad))
                return -1;
            memcpy(c->x, c->xnew, sizeof(double) * (size_t)D->n);
            logf_(c, fmi2OK, "logAll", "event %d at t = %.17g", k, c->t);
            c->side[k] = d != 0 ? d : -s;
            changed = 1;
        } else if (d == 0 && g != 0.0) {
            c->side[k] = g > 0 ? 1.0 : -1.0;
        }
    }
    c->dirty |= changed;
    return changed;
}

static void set_defaults(inst_t *c)
{
    memcpy(c->p, D->param_start, sizeof(double) * (size_t)D->np);
    for (int k = 0; k < D->nu; k++) {
        c->p[U0() + k] = D->input_start[k];
        c->p[M0() + k] = 1.0;
    }
    c->t = c->t_start = 0.0;
    c->t_stop = INFINITY;
    c->stop_defined = 0;
    c->rtol = D->rtol;
    c->seg_end = INFINITY;
    c->init_dirty = 1;
    c->dirty = 1;
    c->eval_failed = 0;
    do_init(c);
}

/* ---- instances ------------------------------------------------------------------------ */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn)
{
    (void)fmuResourceLocation; (void)visible;
    fmi2CallbackLogger logger = functions ? functions->logger : NULL;
    fmi2ComponentEnvironment env = functions ? functions->componentEnvironment : NULL;
    const char *nm = instanceName ? instanceName : "";
#define REFUSE(msg) do { if (logger) logger(env, nm, fmi2Error, "logStatusError", msg); \
                         return NULL; } while (0)
    if (!instanceName || !instanceName[0]) REFUSE("fmi2Instantiate: missing instance name");
    if (!fmuGUID || strcmp(fmuGUID, D->guid) != 0)
        REFUSE("fmi2Instantiate: the GUID does not match this FMU's modelDescription.xml");
#ifdef BGCF_NO_ME
    if (fmuType == fmi2ModelExchange) REFUSE("fmi2Instantiate: this FMU has no Model Exchange");
#endif
#ifdef BGCF_NO_CS
    if (fmuType == fmi2CoSimulation) REFUSE("fmi2Instantiate: this FMU has no Co-Simulation");
#endif
    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation)
        REFUSE("fmi2Instantiate: unknown FMU type");
#undef REFUSE
    inst_t *c = calloc(1, sizeof *c);
    size_t nd = (size_t)(3 * D->n + D->np_all + D->nout + D->nnz + D->nu) + 1;
    double *mem = c ? calloc(nd, sizeof(double)) : NULL;
    if (!c || !mem) {
        free(c);
        free(mem);
        if (logger) logger(env, nm, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return NULL;
    }
    c->magic = MAGIC;
    c->type = fmuType;
    c->logger = logger;
    c->env = env;
    c->logging = loggingOn;
    snprintf(c->name, sizeof c->name, "%s", instanceName);
    c->x = mem;
    c->dx = c->x + D->n;
    c->xnew = c->dx + D->n;
    c->p = c->xnew + D->n;
    c->y = c->p + D->np_all;
    c->jv = c->y + D->nout;
    c->u = c->jv + D->nnz;
    if (D->nev > 0 && !(c->side = calloc(2 * (size_t)D->nev, sizeof(double)))) {
        free(mem);
        free(c);
        if (logger) logger(env, nm, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return NULL;
    }
    c->g = c->side ? c->side + D->nev : NULL;
    set_defaults(c);
    c->state = S_INSTANTIATED;
    return c;
}

void fmi2FreeInstance(fmi2Component comp)
{
    inst_t *c = as_inst(comp);
    if (!c) return;
    c->magic = 0;
    free(c->x);
    free(c->side);
    free(c);
}

fmi2Status fmi2SetDebugLogging(fmi2Component comp, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    inst_t *c = as_inst(comp);
    if (!c) return fmi2Error;
    if (nCategories > 0 && !categories) return ERR(c, "fmi2SetDebugLogging: categories is NULL");
    for (size_t i = 0; i < nCategories; i++) {
        const char *cat = categories[i];
        if (!cat || (strcmp(cat, "logStatusError") && strcmp(cat, "logStatusDiscard") &&
                     strcmp(cat, "logAll")))
            return ERR(c, "fmi2SetDebugLogging: unknown log category (see LogCategories in "
                          "modelDescription.xml)");
    }
    c->logging = loggingOn;
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component comp, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    ENTER(comp, S_INSTANTIATED, "fmi2SetupExperiment")
    if (!isfinite(startTime)) return ERR(c, "fmi2SetupExperiment: start time not finite");
    if (stopTimeDefined && !(stopTime >= startTime))
        return ERR(c, "fmi2SetupExperiment: stop time %g before start time %g", stopTime,
                   startTime);
    if (toleranceDefined) {
        if (!(tolerance > 0) || !isfinite(tolerance))
            return ERR(c, "fmi2SetupExperiment: tolerance must be positive");
        c->rtol = tolerance;
    }
    c->t = c->t_start = startTime;
    c->stop_defined = stopTimeDefined;
    c->t_stop = stopTimeDefined ? stopTime : INFINITY;
    c->dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component comp)
{
    ENTER(comp, S_INSTANTIATED, "fmi2EnterInitializationMode")
    c->init_dirty = 1;
    c->state = S_INIT;
    return fmi2OK;
}

/* closed kinematic loops: the start (from the start values the importer set) against the
 * constraints, as bgc's simulate checks a start: each closure (positions) and each
 * constraint's flow (velocities) within 1e-8 of the state's scale (1 at least). 0 when they
 * hold; else the message naming the constraint and its residual is logged and 1 returned. */
static int constraints_broken(inst_t *c)
{
    int m = D->ncons;
    if (!m) return 0;
    double *r = (double *)calloc((size_t)(2 * m + 1), sizeof(double));
    if (!r) {
        logf_(c, fmi2Error, "logStatusError", "fmi2ExitInitializationMode: out of memory");
        return 1;
    }
    if (D->cons(c->t, c->x, c->p, r) || !all_finite(r, 2 * m, NULL)) {
        free(r);
        logf_(c, fmi2Error, "logStatusError", "fmi2ExitInitializationMode: the closed loops' "
              "constraints are not finite at the start");
        return 1;
    }
    double tol = 1.0;
    for (int i = 0; i < D->n; i++) tol = fmax(tol, fabs(c->x[i]));
    tol *= 1e-8;
    for (int k0 = 0; k0 < m;) {
        int k1 = k0 + 1;
        while (k1 < m && strcmp(D->cons_names[k1], D->cons_names[k0]) == 0) k1++;
        for (int kind = 0; kind < 2; kind++) {
            const double *v = r + kind * m;
            int bad = 0;
            for (int k = k0; k < k1; k++) bad |= !(fabs(v[k]) <= tol);
            if (!bad) continue;
            char shown[400];
            size_t len = 0;
            shown[0] = '\0';
            for (int k = k0; k < k1 && len + 40 < sizeof shown; k++)
                len += (size_t)snprintf(shown + len, sizeof shown - len, "%s%.6g",
                                        k > k0 ? ", " : "", v[k]);
            logf_(c, fmi2Error, "logStatusError",
                  "fmi2ExitInitializationMode: constraint '%s' closing a kinematic loop: the "
                   "initial %s: the residual is [%s] (SI units of the bond's %s); the start "
                   "values break the loop: give start values (parameters) that close it",
                D->cons_names[k0], kind ? "velocities violate it" :
                "positions violate its closure", shown, kind ? "flow" : "displacement");
            free(r);
            return 1;
        }
        k0 = k1;
    }
    free(r);
    return 0;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component comp)
{
    ENTER(comp, S_INIT, "fmi2ExitInitializationMode")
    do_init(c);
    if (evaluate(c)) return ERR(c, "fmi2ExitInitializationMode: the model is not finite at "
                                   "the start");
    if (constraints_broken(c)) return fmi2Error;
    c->seg_end = next_break(c->t);
    c->state = c->type == fmi2ModelExchange ? S_EVENT : S_STEP_COMPLETE;
    if (events_start(c)) return ERR(c, "fmi2ExitInitializationMode: an event indicator is not "
                                       "finite at the start");
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component comp)
{
    ENTER(comp, S_EVENT | S_CONT | S_STEP_COMPLETE | S_STEP_FAILED, "fmi2Terminate")
    c->state = S_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component comp)
{
    inst_t *c = as_inst(comp);
    if (!c) return fmi2Error;
    set_defaults(c);
    c->state = S_INSTANTIATED;
    return fmi2OK;
}

/* ---- values ----------------------------------------------------------------------------- */

#define S_GET_ALL (S_INIT | S_EVENT | S_CONT | S_STEP_COMPLETE | S_STEP_FAILED | S_TERMINATED | S_ERROR)

fmi2Status fmi2GetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[])
{
    ENTER(comp, S_GET_ALL, "fmi2GetReal")
    if (nvr == 0) return fmi2OK;
    if (!vr || !value) return ERR(c, "fmi2GetReal: NULL array");
    for (size_t i = 0; i < nvr; i++)
        if (vr[i] >= (fmi2ValueReference)NVR())
            return ERR(c, "fmi2GetReal: unknown value reference %u", (unsigned)vr[i]);
    int need = 0;
    for (size_t i = 0; i < nvr; i++)
        need |= (int)vr[i] < VR_P() || (int)vr[i] >= VR_U();
    fmi2Status st = fmi2OK;
    if (c->init_dirty) do_init(c);
    if (need && evaluate(c)) st = fmi2Error;
    double *uu = c->u;  /* (no VLAs: the sources build with C compilers without them) */
    if (D->nu) D->input_defaults(t_model(c), c->p, uu);
    for (size_t i = 0; i < nvr; i++) {
        int r = (int)vr[i];
        if (r < D->n) value[i] = c->x[r];
        else if (r < VR_P()) value[i] = c->dx[r - D->n];
        else if (r < VR_U()) value[i] = c->p[r - VR_P()];
        else if (r < VR_Y()) {
            int k = r - VR_U();
            value[i] = c->p[M0() + k] != 0.0 ? uu[k] : c->p[U0() + k];
        } else value[i] = c->y[r - VR_Y()];
    }
    return st;
}

fmi2Status fmi2SetReal(fmi2Component comp, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[])
{
    ENTER(comp, S_INSTANTIATED | S_INIT | S_EVENT | S_CONT | S_STEP_COMPLETE, "fmi2SetReal")
    if (nvr == 0) return fmi2OK;
    if (!vr || !value) return ERR(c, "fmi2SetReal: NULL array");
    /* check everything first: a refused call changes nothing */
    for (size_t i = 0; i < nvr; i++) {
        int r = (int)vr[i];
        if (vr[i] >= (fmi2ValueReference)NVR())
            return ERR(c, "fmi2SetReal: unknown value reference %u", (unsigned)vr[i]);
        if (!isfinite(value[i]))
            return ERR(c, "fmi2SetReal: value reference %u: the value is not finite", (unsigned)vr[i]);
        if (r < VR_P() || r >= VR_Y())
            return ERR(c, "fmi2SetReal: value reference %u is a state, derivative or output "
                          "(set states with fmi2SetContinuousStates)", (unsigned)vr[i]);
        if (r < VR_U()) {
            int k = r - VR_P();
            int ok = (c->state & (S_INSTANTIATED | S_INIT)) ||
                     (D->param_tunable[k] && (c->state & (S_EVENT | S_STEP_COMPLETE)));
            if (!ok)
                return ERR(c, "fmi2SetReal: parameter (value reference %u) cannot be set now%s",
                           (unsigned)vr[i], D->param_tunable[k] ? "" : " (it is fixed)");
        }
    }
    for (size_t i = 0; i < nvr; i++) {
        int r = (int)vr[i];
        if (r < VR_U()) {
            c->p[r - VR_P()] = value[i];
            if (c->state & (S_INSTANTIATED | S_INIT)) c->init_dirty = 1;
            else D->derived(c->p);
        } else {
            int k = r - VR_U();
            c->p[U0() + k] = value[i];
            c->p[M0() + k] = 0.0;
        }
    }
    c->dirty = 1;
    return fmi2OK;
}

static fmi2Status no_vars(fmi2Component comp, size_t nvr, const void *vr, const void *v,
                          const char *fn)
{
    ENTER(comp, S_ANY_ME | S_ANY_CS, fn)
    if (nvr == 0) return fmi2OK;
    if (!vr || !v) return ERR(c, "%s: NULL array", fn);
    return ERR(c, "%s: unknown value reference %u (the FMU has no variables of this type)", fn,
               (unsigned)((const fmi2ValueReference *)vr)[0]);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[])
{ return no_vars(c, nvr, vr, value, "fmi2GetInteger"); }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[])
{ return no_vars(c, nvr, vr, value, "fmi2GetBoolean"); }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[])
{ return no_vars(c, nvr, vr, value, "fmi2GetString"); }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[])
{ return no_vars(c, nvr, vr, value, "fmi2SetInteger"); }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[])
{ return no_vars(c, nvr, vr, value, "fmi2SetBoolean"); }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[])
{ return no_vars(c, nvr, vr, value, "fmi2SetString"); }

/* ---- FMU state: a snapshot of the instance (not serialisable) ---------------------------- */

typedef struct {
    unsigned magic;
    int state, stop_defined, init_dirty;
    double t, t_start, t_stop, rtol, seg_end;
    double *x, *p;
} snap_t;

#define SNAP_MAGIC 0xB6C25A50u
#define S_SNAP (S_INIT | S_EVENT | S_CONT | S_STEP_COMPLETE | S_STEP_FAILED | S_TERMINATED | S_ERROR)

fmi2Status fmi2GetFMUstate(fmi2Component comp, fmi2FMUstate *s)
{
    ENTER(comp, S_SNAP, "fmi2GetFMUstate")
    if (!s) return ERR(c, "fmi2GetFMUstate: FMUstate is NULL");
    snap_t *k = (snap_t *)*s;
    if (k && k->magic != SNAP_MAGIC)
        return ERR(c, "fmi2GetFMUstate: *FMUstate is not a state of this FMU");
    if (!k) {
        k = calloc(1, sizeof *k);
        double *mem = k ? calloc((size_t)(D->n + D->np_all) + 1, sizeof(double)) : NULL;
        if (!k || !mem) {
            free(k);
            free(mem);
            return ERR(c, "fmi2GetFMUstate: out of memory");
        }
        k->magic = SNAP_MAGIC;
        k->x = mem;
        k->p = mem + D->n;
    }
    k->state = c->state; k->stop_defined = c->stop_defined; k->init_dirty = c->init_dirty;
    k->t = c->t; k->t_start = c->t_start; k->t_stop = c->t_stop; k->rtol = c->rtol;
    k->seg_end = c->seg_end;
    memcpy(k->x, c->x, sizeof(double) * (size_t)D->n);
    memcpy(k->p, c->p, sizeof(double) * (size_t)D->np_all);
    *s = k;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component comp, fmi2FMUstate s)
{
    ENTER(comp, S_SNAP, "fmi2SetFMUstate")
    const snap_t *k = (const snap_t *)s;
    if (!k || k->magic != SNAP_MAGIC)
        return ERR(c, "fmi2SetFMUstate: not a state of this FMU");
    c->state = k->state; c->stop_defined = k->stop_defined; c->init_dirty = k->init_dirty;
    c->t = k->t; c->t_start = k->t_start; c->t_stop = k->t_stop; c->rtol = k->rtol;
    c->seg_end = k->seg_end;
    memcpy(c->x, k->x, sizeof(double) * (size_t)D->n);
    memcpy(c->p, k->p, sizeof(double) * (size_t)D->np_all);
    c->dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component comp, fmi2FMUstate *s)
{
    inst_t *c = as_inst(comp);
    if (!c) return fmi2Error;
    if (!s) return ERR(c, "fmi2FreeFMUstate: FMUstate is NULL");
    snap_t *k = (snap_t *)*s;
    if (!k) return fmi2OK;
    if (k->magic != SNAP_MAGIC) return ERR(c, "fmi2FreeFMUstate: not a state of this FMU");
    k->magic = 0;
    free(k->x);
    free(k);
    *s = NULL;
    return fmi2OK;
}

/* ---- serialisation, input and output derivatives: not supported ------------------------- */

fmi2Status fmi2SerializedFMUstateSize(fmi2Component comp, fmi2FMUstate s, size_t *n)
{ (void)s; (void)n; inst_t *c = as_inst(comp); return ERR(c, "fmi2SerializedFMUstateSize: not supported"); }
fmi2Status fmi2SerializeFMUstate(fmi2Component comp, fmi2FMUstate s, fmi2Byte b[], size_t n)
{ (void)s; (void)b; (void)n; inst_t *c = as_inst(comp); return ERR(c, "fmi2SerializeFMUstate: not supported"); }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component comp, const fmi2Byte b[], size_t n,
                                   fmi2FMUstate *s)
{ (void)s; (void)b; (void)n; inst_t *c = as_inst(comp); return ERR(c, "fmi2DeSerializeFMUstate: not supported"); }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[])
{
    (void)vr; (void)nvr; (void)order; (void)value;
    inst_t *c = as_inst(comp);
    return ERR(c, "fmi2SetRealInputDerivatives: not supported (canInterpolateInputs is false)");
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component comp, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[])
{
    (void)vr; (void)nvr; (void)order; (void)value;
    inst_t *c = as_inst(comp);
    return ERR(c, "fmi2GetRealOutputDerivatives: not supported (maxOutputDerivativeOrder is 0)");
}

/* ---- directional derivatives ------------------------------------------------------------ */

/* d(unknowns)/d(knowns) * dv: unknowns are derivatives or outputs, knowns states or inputs.
 * Derivatives with respect to states come from the analytic Jacobian; anything else (outputs,
 * inputs) from central differences of the model functions. */
fmi2Status fmi2GetDirectionalDerivative(fmi2Component comp, const fmi2ValueReference vU[],
                                        size_t nU, const fmi2ValueReference vK[], size_t nK,
                                        const fmi2Real dvK[], fmi2Real dvU[])
{
    ENTER(comp, S_INIT | S_EVENT | S_CONT | S_STEP_COMPLETE | S_STEP_FAILED | S_TERMINATED,
          "fmi2GetDirectionalDerivative")
    if (nU == 0) return fmi2OK;
    if (!vU || !dvU || (nK > 0 && (!vK || !dvK)))
        return ERR(c, "fmi2GetDirectionalDerivative: NULL array");
    int analytic = 1;
    for (size_t i = 0; i < nU; i++) {
        int r = (int)vU[i];
        if (vU[i] >= (fmi2ValueReference)NVR() || !((r >= D->n && r < VR_P()) || r >= VR_Y()))
            return ERR(c, "fmi2GetDirectionalDerivative: value reference %u is not a derivative "
                          "or an output", (unsigned)vU[i]);
        if (r >= VR_Y()) analytic = 0;
    }
    for (size_t i = 0; i < nK; i++) {
        int r = (int)vK[i];
        if (vK[i] >= (fmi2ValueReference)NVR() || !(r < D->n || (r >= VR_U() && r < VR_Y())))
            return ERR(c, "fmi2GetDirectionalDerivative: value reference %u is not a state or "
                          "an input", (unsigned)vK[i]);
        if (!isfinite(dvK[i]))
            return ERR(c, "fmi2GetDirectionalDerivative: a seed value is not finite");
        if (r >= D->n) analytic = 0;
    }
    if (c->init_dirty) do_init(c);
    double t = t_model(c);
    if (analytic) {
        /* v = sum_k dvK[k] e_{vK[k]}; (J v)_i = sum_e [row_e = i] jv_e v[col_e] */
        double *v = c->xnew;
        memset(v, 0, sizeof(double) * (size_t)D->n);
        for (size_t i = 0; i < nK; i++) v[vK[i]] += dvK[i];
        if (D->model->jac(t, c->x, c->p, c->jv) != 0 || !all_finite(c->jv, D->nnz, NULL))
            return ERR(c, "fmi2GetDirectionalDerivative: the Jacobian is not finite");
        for (size_t i = 0; i < nU; i++) {
            int row = (int)vU[i] - D->n;
            double s = 0.0;
            for (int e = 0; e < D->nnz; e++)
                if (D->model->jac_row[e] == row) s += c->jv[e] * v[D->model->jac_col[e]];
            dvU[i] = s;
        }
        return fmi2OK;
    }
    /* central differences along the seed direction */
    double nrm = 0.0;
    for (size_t i = 0; i < nK; i++) nrm = fmax(nrm, fabs(dvK[i]));
    if (nrm == 0.0) { for (size_t i = 0; i < nU; i++) dvU[i] = 0.0; return fmi2OK; }
    size_t m = (size_t)(D->n + D->nout);
    double *buf = malloc(sizeof(double) * (2 * m + (size_t)D->n + (size_t)D->np_all) + 1);
    if (!buf) return ERR(c, "fmi2GetDirectionalDerivative: out of memory");
    double *fp = buf, *fm = buf + m, *xs = fm + m, *ps = xs + D->n;
    double scale = 0.0;
    for (size_t i = 0; i < nK; i++) {
        int r = (int)vK[i];
        double base = r < D->n ? c->x[r] : c->p[U0() + r - VR_U()];
        scale = fmax(scale, fabs(base));
    }
    double h = cbrt(2.2e-16) * fmax(1.0, scale) / nrm;
    int fail = 0;
    double *uu = c->u;  /* (no VLAs: the sources build with C compilers without them) */
    if (D->nu) D->input_defaults(t, c->p, uu);
    for (int sgn = -1; sgn <= 1 && !fail; sgn += 2) {
        memcpy(xs, c->x, sizeof(double) * (size_t)D->n);
        memcpy(ps, c->p, sizeof(double) * (size_t)D->np_all);
        for (size_t i = 0; i < nK; i++) {
            int r = (int)vK[i];
            if (r < D->n) xs[r] += sgn * h * dvK[i];
            else {
                int k = r - VR_U();
                if (ps[M0() + k] != 0.0) { ps[U0() + k] = uu[k]; ps[M0() + k] = 0.0; }
                ps[U0() + k] += sgn * h * dvK[i];
            }
        }
        double *f = sgn < 0 ? fm : fp;
        fail |= D->model->rhs(t, xs, ps, f) != 0;
        if (D->nout) fail |= D->outputs(t, xs, ps, f + D->n) != 0;
        fail |= !all_finite(f, (int)m, NULL);
    }
    if (!fail)
        for (size_t i = 0; i < nU; i++) {
            int r = (int)vU[i];
            int k = r < VR_P() ? r - D->n : D->n + r - VR_Y();
            dvU[i] = (fp[k] - fm[k]) / (2 * h);
        }
    free(buf);
    return fail ? ERR(c, "fmi2GetDirectionalDerivative: the model is not finite") : fmi2OK;
}

/* ---- Model Exchange --------------------------------------------------------------------- */

fmi2Status fmi2EnterEventMode(fmi2Component comp)
{
    ENTER(comp, S_EVENT | S_CONT, "fmi2EnterEventMode")
    c->state = S_EVENT;
    c->dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component comp, fmi2EventInfo *info)
{
    ENTER(comp, S_EVENT, "fmi2NewDiscreteStates")
    if (!info) return ERR(c, "fmi2NewDiscreteStates: eventInfo is NULL");
    c->seg_end = next_break(c->t);
    c->dirty = 1;
    int fired = events_fire(c);
    if (fired < 0) return ERR(c, "fmi2NewDiscreteStates: an event indicator or a reset is not "
                                 "finite at t = %g", c->t);
    info->newDiscreteStatesNeeded = fmi2False;
    info->terminateSimulation = fmi2False;
    info->nominalsOfContinuousStatesChanged = fmi2False;
    info->valuesOfContinuousStatesChanged = fired ? fmi2True : fmi2False;
    info->nextEventTimeDefined = isfinite(c->seg_end) ? fmi2True : fmi2False;
    info->nextEventTime = isfinite(c->seg_end) ? c->seg_end : 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component comp)
{
    ENTER(comp, S_EVENT, "fmi2EnterContinuousTimeMode")
    c->seg_end = next_break(c->t);
    c->state = S_CONT;
    c->dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component comp,
                                       fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    ENTER(comp, S_CONT, "fmi2CompletedIntegratorStep")
    if (!enterEventMode || !terminateSimulation)
        return ERR(c, "fmi2CompletedIntegratorStep: NULL argument");
    *enterEventMode = fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component comp, fmi2Real time)
{
    ENTER(comp, S_EVENT | S_CONT, "fmi2SetTime")
    if (!isfinite(time)) return ERR(c, "fmi2SetTime: time is not finite");
    c->t = time;
    c->dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component comp, const fmi2Real x[], size_t nx)
{
    ENTER(comp, S_CONT, "fmi2SetContinuousStates")
    if (nx != (size_t)D->n) return ERR(c, "fmi2SetContinuousStates: %u states given, the model "
                                          "has %d", (unsigned)nx, D->n);
    if (nx == 0) return fmi2OK;
    if (!x) return ERR(c, "fmi2SetContinuousStates: x is NULL");
    int bad = -1;
    if (!all_finite(x, D->n, &bad))
        return ERR(c, "fmi2SetContinuousStates: state %d is not finite", bad);
    memcpy(c->x, x, sizeof(double) * nx);
    c->dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component comp, fmi2Real dx[], size_t nx)
{
    ENTER(comp, S_INIT | S_EVENT | S_CONT | S_TERMINATED | S_ERROR, "fmi2GetDerivatives")
    if (nx != (size_t)D->n) return ERR(c, "fmi2GetDerivatives: %u states asked for, the model "
                                          "has %d", (unsigned)nx, D->n);
    if (nx == 0) return fmi2OK;
    if (!dx) return ERR(c, "fmi2GetDerivatives: dx is NULL");
    if (evaluate(c)) return fmi2Error;
    memcpy(dx, c->dx, sizeof(double) * nx);
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component comp, fmi2Real ind[], size_t ni)
{
    ENTER(comp, S_INIT | S_EVENT | S_CONT | S_TERMINATED | S_ERROR, "fmi2GetEventIndicators")
    if (ni != (size_t)D->nev) return ERR(c, "fmi2GetEventIndicators: %u indicators asked for, "
                                            "the model has %d", (unsigned)ni, D->nev);
    if (ni == 0) return fmi2OK;
    if (!ind) return ERR(c, "fmi2GetEventIndicators: ind is NULL");
    if (c->init_dirty) do_init(c);
    if (guards_now(c)) return ERR(c, "fmi2GetEventIndicators: an indicator is not finite at "
                                     "t = %g", c->t);
    memcpy(ind, c->g, sizeof(double) * ni);
    /* a guard still zero where the run started is shown on the side before its event (the
     * smallest normal number): leaving zero, it changes sign for the environment to find */
    for (int k = 0; k < D->nev; k++)
        if (c->side[k] == -0.5 * D->ev_dir[k] && ind[k] == 0.0) ind[k] = -D->ev_dir[k] * DBL_MIN;
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component comp, fmi2Real x[], size_t nx)
{
    ENTER(comp, S_INIT | S_EVENT | S_CONT | S_TERMINATED | S_ERROR, "fmi2GetContinuousStates")
    if (nx != (size_t)D->n) return ERR(c, "fmi2GetContinuousStates: %u states asked for, the "
                                          "model has %d", (unsigned)nx, D->n);
    if (nx == 0) return fmi2OK;
    if (!x) return ERR(c, "fmi2GetContinuousStates: x is NULL");
    if (c->init_dirty) do_init(c);
    memcpy(x, c->x, sizeof(double) * nx);
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component comp, fmi2Real nom[], size_t nx)
{
    ENTER(comp, S_ANY_ME, "fmi2GetNominalsOfContinuousStates")
    if (nx != (size_t)D->n) return ERR(c, "fmi2GetNominalsOfContinuousStates: %u states asked "
                                          "for, the model has %d", (unsigned)nx, D->n);
    if (nx == 0) return fmi2OK;
    if (!nom) return ERR(c, "fmi2GetNominalsOfContinuousStates: NULL array");
    /* the scene's absolute tolerance over its relative one: importers that take
     * atol = nominal * rtol (FMPy does) then use the scene's tolerances */
    double nominal = D->atol / D->rtol;
    for (size_t i = 0; i < nx; i++) nom[i] = nominal;
    return fmi2OK;
}

/* ---- Co-Simulation ---------------------------------------------------------------------- */

/* Jacobian values on the pattern by forward differences of the rhs: the fallback of a step
 * whose analytic Jacobian is not finite (e.g. sqrt(|e|) at e = 0 in a flow law) */
static int fd_jac(double t, const double *x, const double *p, double *jv)
{
    int n = D->n;
    double *buf = malloc(sizeof(double) * (size_t)(3 * n) + 1);
    if (!buf) return 1;
    double *f0 = buf, *f1 = buf + n, *xs = buf + 2 * n;
    int rc = D->model->rhs(t, x, p, f0);
    memcpy(xs, x, sizeof(double) * (size_t)n);
    for (int j = 0; j < n && !rc; j++) {
        double h = 1.4901161193847656e-08 * fmax(1.0, fabs(x[j]));
        xs[j] = x[j] + h;
        h = xs[j] - x[j];
        rc = D->model->rhs(t, xs, p, f1);
        xs[j] = x[j];
        for (int e = 0; e < D->nnz; e++)
            if (D->model->jac_col[e] == j) jv[e] = (f1[D->model->jac_row[e]] - f0[D->model->jac_row[e]]) / h;
    }
    /* (bgc's patterns have each (row, col) once) */
    free(buf);
    return rc;
}

/* one communication step: the runtime sees a step's guards at most up to the last double
 * before t1 (its one-sided window), and the next step starts from their signs at t1, so a
 * guard crossing zero in that last ulp (a source's zero at a communication point) would be
 * lost between two steps: its event fires here, at t1, in declaration order. */
static int step_to(inst_t *c, double t1, bgc_options *opt, bgc_stats *st)
{
    int rc = bgc_integrate(D->model, c->p, c->t, t1, c->x, opt, c->xnew, st);
    if (rc != BGC_OK || D->nev == 0 || !(t1 > c->t)) return rc;
    double *g = malloc(sizeof(double) * (2 * (size_t)D->nev + (size_t)D->n));
    if (!g) return BGC_ERR_ARGS;
    double *g1 = g + D->nev, *xa = g1 + D->nev;
    if (D->guards(nextafter(t1, c->t), c->xnew, c->p, g) == 0) {
        for (int k = 0; k < D->nev; k++) {
            if (D->model->ev_timed && D->model->ev_timed[k]) continue;
            if (D->guards(t1, c->xnew, c->p, g1) != 0) break;
            int d = D->ev_dir[k];
            if (!(g[k] * g1[k] < 0) || (d != 0 && (g1[k] > 0 ? 1 : -1) != d)) continue;
            memcpy(xa, c->xnew, sizeof(double) * (size_t)D->n);
            if (D->reset(k, t1, xa, c->p, c->xnew) != 0) { rc = BGC_ERR_MODEL; break; }
            logf_(c, fmi2OK, "logAll", "event %d at t = %.17g (a communication point)", k, t1);
        }
    }
    free(g);
    return rc;
}

fmi2Status fmi2DoStep(fmi2Component comp, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    ENTER(comp, S_STEP_COMPLETE, "fmi2DoStep")
    if (c->type != fmi2CoSimulation) return ERR(c, "fmi2DoStep: not a Co-Simulation instance");
    double t0 = currentCommunicationPoint, h = communicationStepSize;
    if (!isfinite(t0) || !isfinite(h) || h < 0)
        return ERR(c, "fmi2DoStep: bad communication point %g or step size %g", t0, h);
    if (fabs(t0 - c->t) > 1e-9 * fmax(1.0, fabs(c->t)))
        return ERR(c, "fmi2DoStep: the communication point %.17g is not the instance's time "
                      "%.17g", t0, c->t);
    if (h == 0) return fmi2OK;
    if (c->init_dirty) do_init(c);
    double t1 = c->t + h;
    double atol = D->atol * (c->rtol / D->rtol);
    bgc_options opt;
    memset(&opt, 0, sizeof opt);
    opt.method = D->method;
    opt.rtol = c->rtol;
    opt.atol = &atol;
    opt.atol_len = 1;
    opt.max_step = D->max_step;
    opt.max_steps = 1000000;
    opt.t_out = &t1;
    opt.n_out = 1;
    opt.breaks = D->breaks;
    opt.n_breaks = D->n_breaks;
    bgc_stats st;
    memset(&st, 0, sizeof st);
    int rc = step_to(c, t1, &opt, &st);
    if (rc == BGC_ERR_NONFINITE && st.bad_where == 1) {
        /* the analytic Jacobian is not finite somewhere on the way: again with differences */
        bgc_model fd = *D->model;
        fd.jac = fd_jac;
        logf_(c, fmi2OK, "logAll", "fmi2DoStep: %s; again with a difference Jacobian",
              st.message);
        memset(&st, 0, sizeof st);
        rc = bgc_integrate(&fd, c->p, c->t, t1, c->x, &opt, c->xnew, &st);
    }
    if (rc != BGC_OK || !all_finite(c->xnew, D->n, NULL)) {
        st.message[sizeof st.message - 1] = '\0';
        logf_(c, fmi2Discard, "logStatusDiscard", "fmi2DoStep: the integration from t = %g to "
              "%g failed: %s", c->t, t1, st.message);
        c->state = S_STEP_FAILED;
        return fmi2Discard;
    }
    memcpy(c->x, c->xnew, sizeof(double) * (size_t)D->n);
    c->t = t1;
    c->dirty = 1;
    if (evaluate(c)) {
        c->state = S_STEP_FAILED;
        return fmi2Discard;
    }
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component comp)
{
    ENTER(comp, S_ANY_CS, "fmi2CancelStep")
    return ERR(c, "fmi2CancelStep: fmi2DoStep never returns fmi2Pending (it runs synchronously)");
}

fmi2Status fmi2GetStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Status *value)
{
    (void)s; (void)value;
    ENTER(comp, S_STEP_COMPLETE | S_STEP_FAILED, "fmi2GetStatus")
    return ERR(c, "fmi2GetStatus: no asynchronous step to report on");
}

fmi2Status fmi2GetRealStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Real *value)
{
    ENTER(comp, S_STEP_COMPLETE | S_STEP_FAILED, "fmi2GetRealStatus")
    if (!value) return ERR(c, "fmi2GetRealStatus: value is NULL");
    if (s != fmi2LastSuccessfulTime) return ERR(c, "fmi2GetRealStatus: unknown status kind");
    *value = c->t;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s; (void)value;
    ENTER(comp, S_STEP_COMPLETE | S_STEP_FAILED, "fmi2GetIntegerStatus")
    return ERR(c, "fmi2GetIntegerStatus: no integer status");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component comp, const fmi2StatusKind s, fmi2Boolean *value)
{
    ENTER(comp, S_STEP_COMPLETE | S_STEP_FAILED, "fmi2GetBooleanStatus")
    if (!value) return ERR(c, "fmi2GetBooleanStatus: value is NULL");
    if (s != fmi2Terminated) return ERR(c, "fmi2GetBooleanStatus: unknown status kind");
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component comp, const fmi2StatusKind s, fmi2String *value)
{
    (void)s; (void)value;
    ENTER(comp, S_STEP_COMPLETE | S_STEP_FAILED, "fmi2GetStringStatus")
    return ERR(c, "fmi2GetStringStatus: no string status");
}
