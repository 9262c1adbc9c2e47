// BVH traversal with a small per-ray stack (ao4d/bvh.py builds and flattens the tree).
// Node k: bounds lo[k], hi[k]; meta[k] = (left, right) for an inner node, (-(start+1), count)
// for a leaf over simplices start .. start+count-1 (rows of `simplices`, tree order).
#ifndef AO4D_BVH_H
#define AO4D_BVH_H

#include "geometry.h"

// median splits give depth ceil(log2(P / leaf)) + 1; 64 levels hold any mesh that fits memory
#define STACK_SIZE 64

// closest (any_hit = 0) or any (any_hit = 1) hit with 0 < t <= t_max; returns the tree-order
// simplex index or -1, and the distance in *t_out
inline int trace_bvh(__global const float4 *lo, __global const float4 *hi,
                     __global const int2 *meta, __global const float4 *simplices,
                     const float4 o, const float4 w, float t_max, const int any_hit,
                     float *t_out)
{
    const float4 inv_w = 1.0f / w;
    int stack[STACK_SIZE];
    int sp = 0;
    int node = 0;
    int best = -1;
    for (;;) {
        const int2 m = meta[node];
        if (m.x < 0) {
            const int first = -m.x - 1;
            for (int k = first; k < first + m.y; ++k) {
                float t;
                if (hit_simplex(simplices + (size_t)k * SIMPLEX_ROWS, o, w, t_max, &t)) {
                    best = k;
                    t_max = t;
                    if (any_hit) {
                        *t_out = t;
                        return best;
                    }
                }
            }
        } else {
            float tl, tr;
            const bool hl = hit_box(lo[m.x], hi[m.x], o, inv_w, t_max, &tl);
            const bool hr = hit_box(lo[m.y], hi[m.y], o, inv_w, t_max, &tr);
            if (hl && hr) {
                const bool right_first = tr < tl;
                stack[sp++] = right_first ? m.x : m.y;
                node = right_first ? m.y : m.x;
                continue;
            }
            if (hl) { node = m.x; continue; }
            if (hr) { node = m.y; continue; }
        }
        if (sp == 0) break;
        node = stack[--sp];
    }
    *t_out = t_max;
    return best;
}

// the same answer by testing every simplex (for tests and the speed-up benchmark)
inline int trace_brute(__global const float4 *simplices, const int n_simplices, const float4 o,
                       const float4 w, float t_max, const int any_hit, float *t_out)
{
    int best = -1;
    for (int k = 0; k < n_simplices; ++k) {
        float t;
        if (hit_simplex(simplices + (size_t)k * SIMPLEX_ROWS, o, w, t_max, &t)) {
            best = k;
            t_max = t;
            if (any_hit) break;
        }
    }
    *t_out = t_max;
    return best;
}

#endif
