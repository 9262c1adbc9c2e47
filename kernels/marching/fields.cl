// The shape library's fields (ao4d/fields.py) sampled on a grid slab on the device, for
// ao4d/marching/fields_device.py, which appends the field itself: a function
//
//     double field_value(const double *p, __constant const double *prm)
//
// generated from the field's expression tree (Field.program) out of the primitives below, the
// parameters read from `prm`. Every primitive repeats the numpy code of its Python twin
// operation for operation, in double, in the same order and with no contraction (no fused
// multiply-add), so the values are numpy's bit for bit wherever the operations are correctly
// rounded (+ - * /, sqrt, comparisons) or mirrored exactly:
//
//   sumsq     numpy's einsum("...i,...i->...", x, x): with SUMSQ_LANES 2, the even- and the
//             odd-indexed squares summed apart, then added (numpy's two-lane SIMD loop; the
//             Python side checks which order the host's numpy takes); 1: in index order
//   np_hypot  glibc's hypot (2.35 and later, the path without FMA), which numpy's hypot calls
//   np_min, np_max, np_clip01  numpy's NaN-propagating minimum, maximum and clip
//
// exp, sin and cos (metaballs, gyroid) are the device's: not required to be numpy's bits.
//
// Defines (written by ao4d/marching/fields_device.py above this file): DIM (2, 3, 4), SUMSQ_LANES.
// The slab is laid out as ao4d.fields.evaluate_layers lays it: the grid's last axis first, then
// axes 0 .. DIM-2 in C order.

#pragma OPENCL FP_CONTRACT OFF
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

inline double np_min(double a, double b) { return (a <= b || isnan(a)) ? a : b; }
inline double np_max(double a, double b) { return (a >= b || isnan(a)) ? a : b; }
inline double np_clip01(double x) { return np_min(np_max(x, 0.0), 1.0); }

// sum of the squares of x[0 .. n-1], in numpy's einsum order
inline double sumsq(const double *x, int n)
{
#if SUMSQ_LANES == 2
    double even = 0.0, odd = 0.0;
    for (int i = 0; i < n; i += 2) {
        even = even + x[i] * x[i];
        if (i + 1 < n) odd = odd + x[i + 1] * x[i + 1];
    }
    return even + odd;
#else
    double s = 0.0;
    for (int i = 0; i < n; ++i) s = s + x[i] * x[i];
    return s;
#endif
}

inline double norm_of(const double *x, int n) { return sqrt(sumsq(x, n)); }

// glibc's hypot kernel: ax >= ay >= 0, scaled so that no square overflows or underflows
inline double hypot_kernel(double ax, double ay)
{
    double h = sqrt(ax * ax + ay * ay);
    double t1, t2;
    if (h <= 2.0 * ay) {
        const double delta = h - ay;
        t1 = ax * (2.0 * delta - ax);
        t2 = (delta - 2.0 * (ax - ay)) * delta;
    } else {
        const double delta = h - ax;
        t1 = 2.0 * delta * (ax - 2.0 * ay);
        t2 = (4.0 * delta - ay) * ay + delta * delta;
    }
    h = h - (t1 + t2) / (2.0 * h);
    return h;
}

inline double np_hypot(double x, double y)
{
    const double scale = 0x1p-600, large = 0x1p+511, tiny = 0x1p-459, eps = 0x1p-54;
    if (!isfinite(x) || !isfinite(y)) {
        if (isinf(x) || isinf(y)) return INFINITY;
        return x + y;
    }
    x = fabs(x);
    y = fabs(y);
    const double ax = x < y ? y : x, ay = x < y ? x : y;
    if (ax > large) {
        if (ay <= ax * eps) return ax + ay;
        return hypot_kernel(ax * scale, ay * scale) / scale;
    }
    if (ay < tiny) {
        if (ax >= ay / eps) return ax + ay;
        return hypot_kernel(ax / scale, ay / scale) * scale;
    }
    if (ay <= ax * eps) return ax + ay;
    return hypot_kernel(ax, ay);
}

// -- primitives: p the point (DIM coordinates), q the parameters ------------------------------

// hypersphere: |p - c| - r; q = (r, c_0 .. c_{DIM-1})
inline double f_hypersphere(const double *p, __constant const double *q)
{
    double x[DIM];
    for (int i = 0; i < DIM; ++i) x[i] = p[i] - q[1 + i];
    return norm_of(x, DIM) - q[0];
}

// q = (R, r)
inline double f_spheritorus(const double *p, __constant const double *q)
{
    return np_hypot(norm_of(p, 3) - q[0], p[3]) - q[1];
}

// q = (R, r)
inline double f_torisphere(const double *p, __constant const double *q)
{
    const double a = norm_of(p, 2) - q[0];
    return sqrt(a * a + p[2] * p[2] + p[3] * p[3]) - q[1];
}

// q = (R, r1, r2)
inline double f_ditorus(const double *p, __constant const double *q)
{
    const double t = np_hypot(norm_of(p, 2) - q[0], p[2]);
    return np_hypot(t - q[1], p[3]) - q[2];
}

// q = (R1, R2, r)
inline double f_tiger(const double *p, __constant const double *q)
{
    return np_hypot(norm_of(p, 2) - q[0], norm_of(p + 2, 2) - q[1]) - q[2];
}

// q = (r1, r2)
inline double f_duocylinder(const double *p, __constant const double *q)
{
    const double a = norm_of(p, 2) - q[0];
    const double b = norm_of(p + 2, 2) - q[1];
    return np_min(np_max(a, b), 0.0) + np_hypot(np_max(a, 0.0), np_max(b, 0.0));
}

// box of half side a, rounded by rho: q = (a, rho, dim)
inline double f_tesseract(const double *p, __constant const double *q)
{
    double out[DIM];
    double top = fabs(p[0]) - q[0];
    for (int i = 0; i < DIM; ++i) {
        const double d = fabs(p[i]) - q[0];
        out[i] = np_max(d, 0.0);
        top = np_max(top, d);
    }
    return (sqrt(sumsq(out, DIM)) + np_min(top, 0.0)) - q[1];
}

// 1 - sum_i exp(-s (|p - c_i|^2 w_i - 1)); q = (-s, dim, c_0 .. c_{DIM-1}, w_0, c_1 ..., w_1, ...)
inline double f_metaballs(const double *p, __constant const double *q, int balls)
{
    double total = 0.0;
    for (int k = 0; k < balls; ++k) {
        __constant const double *b = q + 2 + k * (DIM + 1);
        double x[DIM];
        for (int i = 0; i < DIM; ++i) x[i] = p[i] - b[i];
        total = total + exp(q[0] * (sumsq(x, DIM) * b[DIM] - 1.0));
    }
    return 1.0 - total;
}

// |sum_i sin(k p_i) cos(k p_{i+1})| - t; q = (k, t)
inline double f_gyroid(const double *p, __constant const double *q)
{
    double s[4], c[4];
    for (int i = 0; i < 4; ++i) {
        const double a = q[0] * p[i];
        s[i] = sin(a);
        c[i] = cos(a);
    }
    double g = 0.0;
    for (int i = 0; i < 4; ++i) g = g + s[i] * c[(i + 1) % 4];
    return fabs(g) - q[1];
}

// p[axis] - h; q = (h, axis, dim)
inline double f_ground(const double *p, __constant const double *q)
{
    return p[(int)q[1]] - q[0];
}

// -- the slab -----------------------------------------------------------------------------------

double field_value(const double *p, __constant const double *prm);

// One work-item per grid point of the slab (shape (layers, n_0, .., n_{DIM-2}), C order), on a
// grid of work-items (n_{DIM-2}, n_{DIM-3}, the rest) with no division in 2D and 3D and one in
// 4D: the point's coordinates read from the grid's axes (`axes`: axis k's coordinates from
// offset o_k), its last coordinate from layer z0 + k. `bad` gets 1 where a value is not finite.
__kernel void sample_field(__global double *out, __global const double *axes,
                     __constant const double *prm, int n0, int o0, int o1, int o2, int o3,
                     int z0, __global int *bad)
{
    const int g0 = (int)get_global_id(0), g1 = (int)get_global_id(1), g2 = (int)get_global_id(2);
    const int g = (g2 * (int)get_global_size(1) + g1) * (int)get_global_size(0) + g0;
    double p[DIM];
#if DIM == 2
    p[0] = axes[o0 + g0];
    p[1] = axes[o1 + z0 + g1];
#elif DIM == 3
    p[0] = axes[o0 + g1];
    p[1] = axes[o1 + g0];
    p[2] = axes[o2 + z0 + g2];
#else
    p[0] = axes[o0 + g2 % n0];
    p[1] = axes[o1 + g1];
    p[2] = axes[o2 + g0];
    p[3] = axes[o3 + z0 + g2 / n0];
#endif
    const double v = field_value(p, prm);
    out[g] = v;
    if (!isfinite(v)) atomic_or(bad, 1);
}
