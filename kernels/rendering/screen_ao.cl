// Screen-space ambient occlusion on a 4D camera's 3D image (host side: ao4d/rendering/screen_ao.py, whose
// numpy path is the reference). DIM is 4. Points arrive relative to the eye (float64 on the
// host, then float32), normals and the camera's basis in world axes.
// One work-item per query point: `samples` cosine-weighted directions (sampling.h, the same as
// the ray-traced AO), each marched in `steps` points q = p + r_k w, r_k = reach (k + 1) / steps,
// from the farthest inwards; a direction counts as occluded at its first q that the image's
// visible surface hides by more than `bias` and less than `thickness` along q's view ray.
//
// The directions are made in world axes (the ray-traced AO's bits), then everything is in the
// camera's basis (a, b, c, d) relative to the eye. The G-buffer is one float4 per voxel (one
// load per look-up): the viewer-facing unit normal's a, b, c components and the depth carrying
// the sign of its d component (inf on background); that component is +-sqrt(1 - x^2 - y^2 -
// z^2). The hit point is the voxel's own ray at that depth. Projections are linear in r along a
// direction, so they are set up once per direction and stepped.
#include "common/sampling.h"

// |u . m| below which the voxel's tangent hyperplane is too oblique to extend to a neighbouring
// view ray: the voxel's own depth is used instead
#define GRAZING 0.1f

// the number of the first `count` of eight directions (camera-basis components w[0..3], one
// direction per lane) from p0 (= p - eye, camera basis) that have a march point hidden by the
// visible surface by more than bias and less than thickness; the eight march together on
// vector lanes, the G-buffer is read lane by lane
inline int marched_hidden8(__global const float4 *gbuffer, const int nx, const int ny,
                           const int nz, const float distance, const int perspective,
                           const float4 grid, const float inv_spacing, const float4 p0,
                           const float8 *w, const int count, const int steps, const float reach,
                           const float bias, const float thickness)
{
    const int8 lane = (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    int8 done = lane >= (int8)(count);  // lanes past the last direction take no part
    int8 hidden = (int8)(0);
    for (int k = steps - 1; k >= 0; --k) {
        const float r = reach * (float)(k + 1) / (float)steps;
        // q - eye in the camera's basis
        const float8 cx = p0.x + r * w[0], cy = p0.y + r * w[1], cz = p0.z + r * w[2];
        const float8 cw = p0.w + r * w[3];
        int8 valid = ~done;
        float8 scale = (float8)(1.0f);
        if (perspective) {
            valid &= cw > 0.0f;  // behind the eye: not in the image
            scale = distance / select((float8)(1.0f), cw, valid);
        }
        const int8 ix = convert_int8(floor((cx * scale - grid.x) * inv_spacing + 0.5f));
        const int8 iy = convert_int8(floor((cy * scale - grid.y) * inv_spacing + 0.5f));
        const int8 iz = convert_int8(floor((cz * scale - grid.z) * inv_spacing + 0.5f));
        valid &= (ix >= 0) & (iy >= 0) & (iz >= 0) & (ix < nx) & (iy < ny) & (iz < nz);
        if (!any(valid)) continue;
        int vi[8], use[8];
        vstore8((ix * ny + iy) * nz + iz, 0, vi);
        vstore8(valid, 0, use);
        float g[4][8];
        for (int j = 0; j < 8; ++j) {
            const float4 v = use[j] ? gbuffer[vi[j]] : (float4)(0.0f, 0.0f, 0.0f, INFINITY);
            g[0][j] = v.x;
            g[1][j] = v.y;
            g[2][j] = v.z;
            g[3][j] = v.w;
        }
        const float8 mx = vload8(0, g[0]), my = vload8(0, g[1]), mz = vload8(0, g[2]);
        const float8 gw = vload8(0, g[3]);
        valid &= ~isinf(gw);  // background: nothing visible there
        const float8 d = fabs(gw);
        const float8 mw = copysign(sqrt(fmax(0.0f, 1.0f - (mx * mx + my * my + mz * mz))), gw);
        // the voxel's hit point minus eye: along its ray (perspective) or from its start on the
        // eye's hyperplane (orthographic); u: q's unit view direction, tq: q's depth
        const float8 ex = grid.x + grid.w * convert_float8(ix);
        const float8 ey = grid.y + grid.w * convert_float8(iy);
        const float8 ez = grid.z + grid.w * convert_float8(iz);
        float8 sx = ex, sy = ey, sz = ez, sw = d, tq = cw;
        float8 ux = (float8)(0.0f), uy = (float8)(0.0f), uz = (float8)(0.0f), uw = (float8)(1.0f);
        if (perspective) {
            const float8 f = d * rsqrt(ex * ex + ey * ey + ez * ez + distance * distance);
            sx = f * ex;
            sy = f * ey;
            sz = f * ez;
            sw = f * distance;
            tq = sqrt(cx * cx + cy * cy + cz * cz + cw * cw);
            const float8 inv = 1.0f / tq;
            ux = cx * inv;
            uy = cy * inv;
            uz = cz * inv;
            uw = cw * inv;
        }
        const float8 um = ux * mx + uy * my + uz * mz + uw * mw;
        const float8 plane = ((cx - sx) * mx + (cy - sy) * my + (cz - sz) * mz + (cw - sw) * mw) / um;
        const float8 delta = select(tq - d, plane, fabs(um) >= GRAZING);
        const int8 now = valid & (delta > bias) & (delta < thickness);
        hidden |= now;
        done |= now;
        if (all(done)) break;
    }
    int out[8];
    vstore8(hidden, 0, out);
    int total = 0;
    for (int j = 0; j < 8; ++j) total += out[j] != 0;
    return total;
}

// vec_type_hint(float4): one point per work-item, its directions eight at a time on the vector
// lanes, marching together on float8 (as the packet AO kernel does; on Intel's CPU runtime this
// measured 2-4x faster than one direction at a time vectorised across work-items)
__kernel __attribute__((vec_type_hint(float4)))
void screen_ao(__global const float4 *gbuffer, const int nx, const int ny, const int nz,
               const float4 eye, const float4 axis_x, const float4 axis_y, const float4 axis_z,
               const float4 view, const float distance, const int perspective, const float4 grid,
               __global const float4 *points, __global const float4 *normals,
               __global const uint *table, const int samples, const uint seed, const int steps,
               const float reach, const float bias, const float thickness, __global int *counts)
{
    const size_t i = get_global_id(0);
    const float4 p = points[i];
    const float4 n = normals[i];
    uint shift[DIM - 1];
    for (int k = 0; k < DIM - 1; ++k) shift[k] = point_shift((uint)i, seed, (uint)k);
    float4 frame[DIM - 1];
    tangent_frame(n, frame);
    const float inv_spacing = 1.0f / grid.w;
    const float4 pe = p - eye;
    const float4 p0 = (float4)(dot(pe, axis_x), dot(pe, axis_y), dot(pe, axis_z), dot(pe, view));
    int occluded = 0;
    for (int s0 = 0; s0 < samples; s0 += 8) {
        // eight directions at once on vector lanes (cosine_directions8: the same bits as
        // cosine_direction), then their camera-basis components
        float8 w8[DIM];
        cosine_directions8(n, frame, table, s0, samples, shift, w8);
        float8 c[4];
        c[0] = w8[0] * axis_x.x + w8[1] * axis_x.y + w8[2] * axis_x.z + w8[3] * axis_x.w;
        c[1] = w8[0] * axis_y.x + w8[1] * axis_y.y + w8[2] * axis_y.z + w8[3] * axis_y.w;
        c[2] = w8[0] * axis_z.x + w8[1] * axis_z.y + w8[2] * axis_z.z + w8[3] * axis_z.w;
        c[3] = w8[0] * view.x + w8[1] * view.y + w8[2] * view.z + w8[3] * view.w;
        occluded += marched_hidden8(gbuffer, nx, ny, nz, distance, perspective, grid, inv_spacing,
                                    p0, c, min(8, samples - s0), steps, reach, bias, thickness);
    }
    counts[i] = occluded;
}

// the G-buffer voxel v's hit point minus eye and unit normal, both in the camera's basis
inline void gbuffer_surface(const float4 g, const int ix, const int iy, const int iz,
                            const float4 grid, const float distance, const int perspective,
                            float4 *s, float4 *m)
{
    const float d = fabs(g.w);
    const float mw = copysign(sqrt(fmax(0.0f, 1.0f - (g.x * g.x + g.y * g.y + g.z * g.z))), g.w);
    *m = (float4)(g.x, g.y, g.z, mw);
    const float4 centre = (float4)(grid.x + grid.w * (float)ix, grid.y + grid.w * (float)iy,
                                   grid.z + grid.w * (float)iz, distance);
    *s = perspective ? d * normalize(centre) : (float4)(centre.x, centre.y, centre.z, d);
}

// Depth- and normal-aware box filter of an occlusion image (ao4d.rendering.screen_ao.denoise): the mean
// over the (2 radius + 1)^3 voxels around v that see a surface whose normal is within
// normal_min (cosine) of v's and whose hit point lies within `tolerance` voxel sizes (at v's
// depth) of v's tangent hyperplane. NaN on background.
__kernel void denoise(__global const float4 *gbuffer, __global const float *occlusion,
                      const int nx, const int ny, const int nz, const float4 grid,
                      const float distance, const int perspective, const int radius,
                      const float tolerance, const float normal_min, __global float *out)
{
    const int v = (int)get_global_id(0);
    const int ix = v / (ny * nz), iy = (v / nz) % ny, iz = v % nz;
    const float4 g = gbuffer[v];
    if (isinf(g.w)) {
        out[v] = NAN;
        return;
    }
    float4 s, m;
    gbuffer_surface(g, ix, iy, iz, grid, distance, perspective, &s, &m);
    // a voxel's size in world units at v's depth
    const float size = perspective ? grid.w * length(s) / length((float4)(
        grid.x + grid.w * (float)ix, grid.y + grid.w * (float)iy, grid.z + grid.w * (float)iz,
        distance)) : grid.w;
    const float limit = tolerance * size;
    float total = 0.0f;
    int count = 0;
    for (int jx = max(0, ix - radius); jx <= min(nx - 1, ix + radius); ++jx)
        for (int jy = max(0, iy - radius); jy <= min(ny - 1, iy + radius); ++jy)
            for (int jz = max(0, iz - radius); jz <= min(nz - 1, iz + radius); ++jz) {
                const int u = (jx * ny + jy) * nz + jz;
                const float4 h = gbuffer[u];
                if (isinf(h.w)) continue;
                float4 t, n;
                gbuffer_surface(h, jx, jy, jz, grid, distance, perspective, &t, &n);
                if (dot(n, m) < normal_min || fabs(dot(t - s, m)) > limit) continue;
                total += occlusion[u];
                ++count;
            }
    out[v] = total / (float)count;  // count >= 1: v itself
}
