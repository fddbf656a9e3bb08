/* bgc runtime: table inputs (data given at knots tk, values vk), evaluated as the numpy
 * module's _table_eval does: linear, pchip (Fritsch-Carlson monotone cubic Hermite, its
 * slopes from the neighbouring secants) or previous (zero-order hold); outside the knots the
 * end value is held, or with extrapolate "error" the call fails. */
#include <math.h>
#include "bgc_runtime.h"

/* the last knot at or before tc (0 when tc is before the first) */
static int last_at_or_before(const double *tk, int n, double tc)
{
    int lo = 0, hi = n; /* the first index with tk[i] > tc lies in [lo, hi] */
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (tk[mid] <= tc) lo = mid + 1;
        else hi = mid;
    }
    return lo > 0 ? lo - 1 : 0;
}

static double sgn(double x) { return (double)((x > 0) - (x < 0)); }

/* the pchip slope at knot j (n >= 3) */
static double pchip_slope(const double *tk, const double *vk, int n, int j)
{
    if (j > 0 && j < n - 1) {
        double h0 = tk[j] - tk[j - 1], h1 = tk[j + 1] - tk[j];
        double s0 = (vk[j] - vk[j - 1]) / h0, s1 = (vk[j + 1] - vk[j]) / h1;
        if (!(s0 * s1 > 0)) return 0.0;
        double w1 = 2 * h1 + h0, w2 = h1 + 2 * h0;
        return (w1 + w2) / (w1 / s0 + w2 / s1);
    }
    /* an end: the one-sided three-point formula, limited to keep the shape */
    int a = j == 0 ? 0 : n - 2, b = j == 0 ? 1 : n - 3;
    double h0 = tk[a + 1] - tk[a], h1 = tk[b + 1] - tk[b];
    double s0 = (vk[a + 1] - vk[a]) / h0, s1 = (vk[b + 1] - vk[b]) / h1;
    double d = ((2 * h0 + h1) * s0 - h0 * s1) / (h0 + h1);
    if (sgn(d) != sgn(s0)) d = 0.0;
    else if (sgn(s0) != sgn(s1) && fabs(d) > fabs(3 * s0)) d = 3 * s0;
    return d;
}

int bgc_table_eval(const double *tk, const double *vk, int n, int interp, int error, double t,
                   double *v)
{
    if (error && (t < tk[0] || t > tk[n - 1])) {
        *v = NAN;
        return 1;
    }
    double tc = t < tk[0] ? tk[0] : (t > tk[n - 1] ? tk[n - 1] : t);
    int i = last_at_or_before(tk, n, tc);
    if (interp == BGC_TABLE_PREVIOUS) {
        *v = vk[i];
        return 0;
    }
    if (i > n - 2) i = n - 2;
    double h = tk[i + 1] - tk[i];
    if (interp == BGC_TABLE_LINEAR) {
        *v = vk[i] + (vk[i + 1] - vk[i]) * (tc - tk[i]) / h;
        return 0;
    }
    double d0, d1;
    if (n == 2) {
        d0 = d1 = (vk[1] - vk[0]) / h;
    } else {
        d0 = pchip_slope(tk, vk, n, i);
        d1 = pchip_slope(tk, vk, n, i + 1);
    }
    double s = (tc - tk[i]) / h;
    double h00 = (1 + 2 * s) * (1 - s) * (1 - s), h10 = s * (1 - s) * (1 - s);
    double h01 = s * s * (3 - 2 * s), h11 = s * s * (s - 1);
    *v = h00 * vk[i] + h10 * h * d0 + h01 * vk[i + 1] + h11 * h * d1;
    return 0;
}
