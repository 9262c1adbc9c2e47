// Closest hits refined in float64 on the device (host side: ao4d.rays.refine._refine_on_device):
// for each hit, the distance t and the barycentric weights on the hit simplex, with the
// operations of ao4d.rays.refine._refine_block on the host, in its order, so that both give the
// same bits. Devices with cl_khr_fp64 only; elsewhere the host refines.
//
// Compile with -D DIM=2|3|4 and -D RAY_T=float|double (the type of the caller's rows).
#ifndef DIM
#error "compile with -D DIM=2|3|4"
#endif
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
// numpy's rounding, operation by operation: no fused multiply-adds anywhere in this file
#pragma OPENCL FP_CONTRACT OFF

#include "common/simplex.h"

// hit k: ray rows origins / directions[k] (the caller's, DIM values each), the mesh simplex
// simplex[k] (vertices in the tree's frame: frame[0 .. DIM) the centre, frame[DIM] the scale),
// written to row rows[k] of t_out (world units) and bary_out (DIM weights, vertex 0 first)
__kernel void refine_hits(__global const RAY_T *origins, __global const RAY_T *directions,
                          __global const double *frame, __global const int *simplex,
                          __global const long *rows, __global const double *vertices,
                          __global const int *simplices, __global double *t_out,
                          __global double *bary_out)
{
    const size_t k = get_global_id(0);
    // the ray in the tree's frame (_Rays.inv_length, Frame.points): the squares summed in
    // column order, then 1 / sqrt in double (not rounded to float as the traversal's is)
    double length2 = 0.0;
    for (int j = 0; j < DIM; ++j) {
        const double x = directions[k * DIM + j];
        length2 += x * x;
    }
    const double inv_length = 1.0 / sqrt(length2);
    double o[DIM], w[DIM];
    for (int j = 0; j < DIM; ++j) {
        o[j] = ((double)origins[k * DIM + j] - frame[j]) * frame[DIM];
        w[j] = (double)directions[k * DIM + j] * inv_length;
    }
    real p[DIM][DIM], e[DIM][DIM], n[DIM], nn, inv[DIM][DIM];
    load_corners(vertices, simplices, simplex[k], p);
    simplex_frame(p, e, n, &nn);
    simplex_inverse(e, n, nn, inv);
    // the hyperplane's row of the inverse: t = -(row . (o - p0)) / (row . w)
    double num = inv[DIM - 1][0] * (o[0] - p[0][0]);
    double den = inv[DIM - 1][0] * w[0];
    for (int j = 1; j < DIM; ++j) {
        num = num + inv[DIM - 1][j] * (o[j] - p[0][j]);
        den = den + inv[DIM - 1][j] * w[j];
    }
    const double t = -num / den;
    double x[DIM];
    for (int j = 0; j < DIM; ++j) x[j] = (o[j] + t * w[j]) - p[0][j];
    const long row = rows[k];
    double sum = 0.0;
    for (int i = 0; i < DIM - 1; ++i) {
        double beta = inv[i][0] * x[0];
        for (int j = 1; j < DIM; ++j) beta = beta + inv[i][j] * x[j];
        bary_out[row * DIM + i + 1] = beta;
        sum = sum + beta;
    }
    bary_out[row * DIM] = 1.0 - sum;
    t_out[row] = t / frame[DIM];
}
