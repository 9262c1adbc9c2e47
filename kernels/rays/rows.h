// cast_rays' rows mapped into the tree's frame (map_ray), for the kernels that take the caller's
// rows (ao.cl's cast_rows_* and map_rays, cast_packets.cl). Include with -D RAY_T defined.
#ifndef AO4D_ROWS_H
#define AO4D_ROWS_H
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

// Rows of DIM RAY_T values, mapped into the tree's frame here, in double, with the operations
// and in the order of ao4d.rays.rows._Rays.chunk on the host, so that the kernels trace the same
// float32 bits: origins float((o - centre) * scale), directions
// float(w * (double)float(1 / sqrt(w0^2 + w1^2 + ...))), the squares summed in column order.
// OpenCL C rounds double +, -, *, /, sqrt and the conversion to float correctly, as numpy does.

// ray i of origins / directions in the frame (frame[0 .. DIM): centre, frame[DIM]: scale);
// 0 for a zero-length direction (the host names it), else 1
inline int map_ray(__global const RAY_T *origins, __global const RAY_T *directions,
                   __global const double *frame, const size_t i, float4 *o4, float4 *w4)
{
#pragma OPENCL FP_CONTRACT OFF
    double length2 = 0.0;
    for (int k = 0; k < DIM; ++k) {
        const double x = directions[i * DIM + k];
        length2 += x * x;
    }
    if (!(length2 > 0.0)) return 0;
    const double inv_length = (double)(float)(1.0 / sqrt(length2));
    float o[4] = {0.0f, 0.0f, 0.0f, 0.0f}, w[4] = {0.0f, 0.0f, 0.0f, 0.0f};
    for (int k = 0; k < DIM; ++k) {
        o[k] = (float)(((double)origins[i * DIM + k] - frame[k]) * frame[DIM]);
        w[k] = (float)((double)directions[i * DIM + k] * inv_length);
    }
    *o4 = vload4(0, o);
    *w4 = vload4(0, w);
    return 1;
}

#endif
