/* Hand-written test models for tests/test_c_runtime.py: rhs and Jacobian values on a fixed
 * pattern, with the signatures of bgc_runtime.h. The test builds the bgc_model structs
 * through ctypes (patterns, n and flags come from the test). */
#include <math.h>

/* diagonal linear system y_i' = lam_i y_i, n = 2, p = (lam_0, lam_1); pattern (0,0), (1,1) */
int lin_rhs(double t, const double *x, const double *p, double *dx)
{
    (void)t;
    dx[0] = p[0] * x[0];
    dx[1] = p[1] * x[1];
    return 0;
}
int lin_jac(double t, const double *x, const double *p, double *jv)
{
    (void)t; (void)x;
    jv[0] = p[0];
    jv[1] = p[1];
    return 0;
}

/* forced mass-spring-damper: x' = v, m v' = -k x - c v + F cos(w t), p = (m, k, c, F, w);
 * pattern (0,1), (1,0), (1,1) */
int msd_rhs(double t, const double *x, const double *p, double *dx)
{
    dx[0] = x[1];
    dx[1] = (-p[1] * x[0] - p[2] * x[1] + p[3] * cos(p[4] * t)) / p[0];
    return 0;
}
int msd_jac(double t, const double *x, const double *p, double *jv)
{
    (void)t; (void)x;
    jv[0] = 1.0;
    jv[1] = -p[1] / p[0];
    jv[2] = -p[2] / p[0];
    return 0;
}

/* a step input, one-sided: x' = -a x + u(t), u = 0 for t < ts, 1 from ts on; p = (a, ts);
 * pattern (0,0) */
int step_rhs(double t, const double *x, const double *p, double *dx)
{
    dx[0] = -p[0] * x[0] + (t < p[1] ? 0.0 : 1.0);
    return 0;
}
int step_jac(double t, const double *x, const double *p, double *jv)
{
    (void)t; (void)x;
    jv[0] = -p[0];
    return 0;
}

/* pendulum: th' = om, om' = -(g/L) sin th, p = (g/L); pattern (0,1), (1,0) */
int pend_rhs(double t, const double *x, const double *p, double *dx)
{
    (void)t;
    dx[0] = x[1];
    dx[1] = -p[0] * sin(x[0]);
    return 0;
}
int pend_jac(double t, const double *x, const double *p, double *jv)
{
    (void)t;
    jv[0] = 1.0;
    jv[1] = -p[0] * cos(x[0]);
    return 0;
}

/* Van der Pol, scaled (problem VDPOL of Hairer & Wanner's stiff test set):
 * y0' = y1, y1' = ((1 - y0^2) y1 - y0) / eps, p = (eps); pattern (0,1), (1,0), (1,1) */
int vdp_rhs(double t, const double *x, const double *p, double *dx)
{
    (void)t;
    dx[0] = x[1];
    dx[1] = ((1.0 - x[0] * x[0]) * x[1] - x[0]) / p[0];
    return 0;
}
int vdp_jac(double t, const double *x, const double *p, double *jv)
{
    (void)t;
    jv[0] = 1.0;
    jv[1] = (-2.0 * x[0] * x[1] - 1.0) / p[0];
    jv[2] = (1.0 - x[0] * x[0]) / p[0];
    return 0;
}

/* a chain of N masses (N = p[0]) joined by springs and dampers, the first to a wall:
 * state (x_0, v_0, x_1, v_1, ...); spring i (left of mass i) has stiffness k_stiff for even
 * i and k_soft for odd i, dampers c; p = (N, k_stiff, k_soft, c, m).
 * Pattern, row by row: x_i: v_i; v_i: x_{i-1}, v_{i-1}, x_i, v_i, x_{i+1}, v_{i+1}. */
static double chain_k(const double *p, int i) { return (i % 2 == 0) ? p[1] : p[2]; }
int chain_rhs(double t, const double *x, const double *p, double *dx)
{
    (void)t;
    int N = (int)p[0];
    double c = p[3], m = p[4];
    for (int i = 0; i < N; i++) {
        double xl = i ? x[2 * i - 2] : 0.0, vl = i ? x[2 * i - 1] : 0.0;
        double f = -chain_k(p, i) * (x[2 * i] - xl) - c * (x[2 * i + 1] - vl);
        if (i + 1 < N)
            f += chain_k(p, i + 1) * (x[2 * i + 2] - x[2 * i]) + c * (x[2 * i + 3] - x[2 * i + 1]);
        dx[2 * i] = x[2 * i + 1];
        dx[2 * i + 1] = f / m;
    }
    return 0;
}
int chain_jac(double t, const double *x, const double *p, double *jv)
{
    (void)t; (void)x;
    int N = (int)p[0], e = 0;
    double c = p[3], m = p[4];
    for (int i = 0; i < N; i++) {
        double kl = chain_k(p, i), kr = i + 1 < N ? chain_k(p, i + 1) : 0.0;
        double cr = i + 1 < N ? c : 0.0;
        jv[e++] = 1.0;                      /* d x_i' / d v_i */
        if (i) { jv[e++] = kl / m; jv[e++] = c / m; }
        jv[e++] = -(kl + kr) / m;
        jv[e++] = -(c + cr) / m;
        if (i + 1 < N) { jv[e++] = kr / m; jv[e++] = c / m; }
    }
    return 0;
}

/* y' = -y, but the rhs of state 1 is NaN once t > p[0] (p[1] != 0: the Jacobian's entry
 * (1,1) instead); pattern (0,0), (1,1) */
int nan_rhs(double t, const double *x, const double *p, double *dx)
{
    dx[0] = -x[0];
    dx[1] = (p[1] == 0.0 && t > p[0]) ? NAN : -x[1];
    return 0;
}
int nan_jac(double t, const double *x, const double *p, double *jv)
{
    (void)x;
    jv[0] = -1.0;
    jv[1] = (p[1] != 0.0 && t > p[0]) ? NAN : -1.0;
    return 0;
}

/* a model whose rhs reports failure (nonzero) once t > 0.5 */
int fail_rhs(double t, const double *x, const double *p, double *dx)
{
    (void)p;
    dx[0] = -x[0];
    return t > 0.5;
}
int fail_jac(double t, const double *x, const double *p, double *jv)
{
    (void)t; (void)x; (void)p;
    jv[0] = -1.0;
    return 0;
}
