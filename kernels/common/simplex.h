// Per-simplex geometry in `real` (double or float, typedef'd by the includer) with the very
// operations of ao4d.bvh.host.frames, in its order: corners, edges from vertex 0, the normal
// (generalised cross product), the degeneracy test and the inverse frame by Cramer's rule.
// Included by bvh_build.cl (leaf blocks, records) and refine.cl (hits in float64); the
// includer compiles with FP_CONTRACT OFF, so that double results equal numpy's bit for bit.
#ifndef AO4D_SIMPLEX_H
#define AO4D_SIMPLEX_H

inline void load_corners(__global const real *vertices, __global const int *simplices, const int s,
                         real p[DIM][DIM])
{
    for (int k = 0; k < DIM; ++k) {
        const int v = simplices[(size_t)s * DIM + k];
        for (int j = 0; j < DIM; ++j) p[k][j] = vertices[(size_t)v * DIM + j];
    }
}

// generalised cross product of DIM-1 vectors (ao4d.geometry.cross_components, same operation
// order; written out so that every index is a constant and the values stay in registers)
inline void cross(const real *a, const real *b, const real *c, real *out)
{
#if DIM == 2
    out[0] = -a[1];
    out[1] = a[0];
#elif DIM == 3
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
#else
    const real m01 = b[0] * c[1] - b[1] * c[0], m02 = b[0] * c[2] - b[2] * c[0];
    const real m03 = b[0] * c[3] - b[3] * c[0], m12 = b[1] * c[2] - b[2] * c[1];
    const real m13 = b[1] * c[3] - b[3] * c[1], m23 = b[2] * c[3] - b[3] * c[2];
    out[0] = -(a[1] * m23 - a[2] * m13 + a[3] * m12);
    out[1] = a[0] * m23 - a[2] * m03 + a[3] * m02;
    out[2] = -(a[0] * m13 - a[1] * m03 + a[3] * m01);
    out[3] = a[0] * m12 - a[1] * m02 + a[2] * m01;
#endif
}

// edges from vertex 0, the normal, |n|^2; returns whether the simplex has non-zero measure
// (ao4d.bvh.host.frames: |n| > 1e-12 * longest edge^(d-1), the power as repeated products, and |n| > 0)
inline int simplex_frame(const real p[DIM][DIM], real e[DIM][DIM], real n[DIM], real *norm2)
{
    for (int k = 1; k < DIM; ++k)
        for (int j = 0; j < DIM; ++j) e[k - 1][j] = p[k][j] - p[0][j];
#if DIM == 2
    cross(e[0], e[0], e[0], n);
#elif DIM == 3
    cross(e[0], e[1], e[1], n);
#else
    cross(e[0], e[1], e[2], n);
#endif
    real longest2 = 0;
    for (int k = 0; k < DIM - 1; ++k) {
        real s = e[k][0] * e[k][0];
        for (int j = 1; j < DIM; ++j) s = s + e[k][j] * e[k][j];
        longest2 = k == 0 ? s : fmax(longest2, s);
    }
    real nn = n[0] * n[0];
    for (int j = 1; j < DIM; ++j) nn = nn + n[j] * n[j];
    *norm2 = nn;
    const real norm = sqrt(nn), longest = sqrt(longest2);
#if DIM == 2
    const real scale = longest;
#elif DIM == 3
    const real scale = longest * longest;
#else
    const real scale = longest * longest * longest;
#endif
    return norm > (real)1e-12 * scale && norm > 0;
}

// rows of inverse([e1 .. e_{d-1} | n]) by Cramer's rule (ao4d.bvh.host.frames): row i is
// (-1)^(d-1-i) X(the columns but i) / |n|^2, the last row n / |n|^2
inline void simplex_inverse(const real e[DIM][DIM], const real n[DIM], const real norm2,
                            real inv[DIM][DIM])
{
    const real plus = (real)1 / norm2, minus = (real)-1 / norm2;
#if DIM == 2
    cross(n, n, n, inv[0]);
    for (int j = 0; j < DIM; ++j) inv[0][j] = inv[0][j] * minus;
#elif DIM == 3
    cross(e[1], n, n, inv[0]);
    cross(e[0], n, n, inv[1]);
    for (int j = 0; j < DIM; ++j) {
        inv[0][j] = inv[0][j] * plus;
        inv[1][j] = inv[1][j] * minus;
    }
#else
    cross(e[1], e[2], n, inv[0]);
    cross(e[0], e[2], n, inv[1]);
    cross(e[0], e[1], n, inv[2]);
    for (int j = 0; j < DIM; ++j) {
        inv[0][j] = inv[0][j] * minus;
        inv[1][j] = inv[1][j] * plus;
        inv[2][j] = inv[2][j] * minus;
    }
#endif
    for (int j = 0; j < DIM; ++j) inv[DIM - 1][j] = n[j] / norm2;
}

#endif
