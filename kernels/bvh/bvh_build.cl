// BVH construction on the OpenCL device (host side: ao4d/bvh_build.py): the binned-SAH tree of
// ao4d/bvh.py, built level by level for large nodes and one work-item per subtree below.
//
// Compile with -D DIM=2|3|4. With -D USE_DOUBLE (devices with cl_khr_fp64) the per-simplex
// geometry (degeneracy test, boxes with margins, centroids, inverse matrices) is computed in
// double with the very operations of ao4d.bvh.host.frames / build, so every simplex's box,
// centroid and leaf-block entries equal the host builder's bit for bit; without it, in float,
// and the degeneracy test comes from the host (-D KEEP_GIVEN), so both keep the same simplices.
//
// Nothing here depends on work-group sizes (every kernel runs with a NULL local size) and no
// kernel uses local memory or float atomics: bins are per-work-item partials reduced by one
// work-item per node, the only atomic is one global int counter that hands out node ids
// (the host renumbers the nodes breadth first afterwards, so the result is deterministic).
//
// Primitive records in tree order: rec[3 i] = box low, rec[3 i + 1] = box high,
// rec[3 i + 2] = centroid (float4, zeros beyond DIM), ids[i] = the simplex.
#ifndef DIM
#error "compile with -D DIM=2|3|4"
#endif

#ifdef USE_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
#define TO_FLOAT(x) ((float)(x))  // round to nearest even (OpenCL C 6.2.3.2)
#else
typedef float real;
#define TO_FLOAT(x) (x)
#endif

// the host's rounding, operation by operation: no fused multiply-adds anywhere in this file
#pragma OPENCL FP_CONTRACT OFF

#define FLT_TRUE_MIN_ as_float(1)  // the smallest subnormal float
#define MAX_BINS 32
#define SAH_MIN_COUNT 16  // ao4d.bvh._SAH_MIN_COUNT: smaller nodes split at the median
#define SAH_MAX_LEVEL 40  // ao4d.bvh._SAH_MAX_LEVEL: deeper nodes split in halves
#ifndef SUBTREE_STACK
#define SUBTREE_STACK 64  // pending nodes of one subtree: depth <= 40 + log2(subtree size) + 1
#endif

// -- per-simplex geometry (double with USE_DOUBLE) ----------------------------------------------

#include "common/simplex.h"

// the neighbours of a finite float towards -inf / +inf (nextafter, without its slow generic path)
inline float next_down(const float x)
{
    if (x == 0.0f) return -FLT_TRUE_MIN_;
    return as_float(x > 0.0f ? as_int(x) - 1 : as_int(x) + 1);
}

inline float next_up(const float x)
{
    if (x == 0.0f) return FLT_TRUE_MIN_;
    return as_float(x > 0.0f ? as_int(x) + 1 : as_int(x) - 1);
}

// pass 1, one work-item per chunk of simplices: keep (1) or skip (0) each, the kept count and
// the kept corners' bounds. With -D KEEP_GIVEN (devices without doubles) `keep` arrives filled
// by the host's float64 test (ao4d.bvh.host.nondegenerate): a float test would keep or skip
// other simplices than the host tree and the numpy backend
__kernel __attribute__((vec_type_hint(float4))) void scan_simplices(
    __global const real *vertices, __global const int *simplices, const int n_simplices,
    const int chunk, __global uchar *keep, __global int *kept, __global real *part_lo,
    __global real *part_hi, __global real *part_abs)
{
    const int c = get_global_id(0);
    const int begin = c * chunk, end = min(n_simplices, begin + chunk);
    real lo[DIM], hi[DIM], big = 0;
    for (int j = 0; j < DIM; ++j) {
        lo[j] = INFINITY;
        hi[j] = -INFINITY;
    }
    int count = 0;
    for (int s = begin; s < end; ++s) {
        real p[DIM][DIM];
        load_corners(vertices, simplices, s, p);
#ifdef KEEP_GIVEN
        const int ok = keep[s];  // decided by the host in float64
#else
        real e[DIM][DIM], n[DIM], nn;
        const int ok = simplex_frame(p, e, n, &nn);
        keep[s] = (uchar)ok;
#endif
        if (!ok) continue;
        ++count;
        for (int k = 0; k < DIM; ++k)
            for (int j = 0; j < DIM; ++j) {
                lo[j] = fmin(lo[j], p[k][j]);
                hi[j] = fmax(hi[j], p[k][j]);
                big = fmax(big, fabs(p[k][j]));
            }
    }
    kept[c] = count;
    for (int j = 0; j < DIM; ++j) {
        part_lo[c * DIM + j] = lo[j];
        part_hi[c * DIM + j] = hi[j];
    }
    part_abs[c] = big;
}

// pass 2, per chunk: records of the kept simplices, compacted in simplex order from offset[c];
// boxes grow by 2 BARY_EPS times the longest extent plus margin (ao4d.bvh.build) and are
// rounded outwards to float32; per-chunk centroid bounds for the root
__kernel __attribute__((vec_type_hint(float4))) void make_records(
    __global const real *vertices, __global const int *simplices, const int n_simplices,
    const int chunk, __global const uchar *keep, __global const int *offset, const real bary2,
    const real margin, __global float4 *rec, __global int *ids, __global float4 *part_c)
{
    const int c = get_global_id(0);
    const int begin = c * chunk, end = min(n_simplices, begin + chunk);
    int out = offset[c];
    float4 c_lo = (float4)(INFINITY), c_hi = (float4)(-INFINITY);
    for (int s = begin; s < end; ++s) {
        if (!keep[s]) continue;
        real p[DIM][DIM];
        load_corners(vertices, simplices, s, p);
        float a[4] = {0, 0, 0, 0}, b[4] = {0, 0, 0, 0}, m[4] = {0, 0, 0, 0};
        real lo[DIM], hi[DIM], ext = 0;
        for (int j = 0; j < DIM; ++j) {
            lo[j] = p[0][j];
            hi[j] = p[0][j];
            real sum = p[0][j];
            for (int k = 1; k < DIM; ++k) {
                lo[j] = fmin(lo[j], p[k][j]);
                hi[j] = fmax(hi[j], p[k][j]);
                sum = sum + p[k][j];
            }
            m[j] = TO_FLOAT(sum / (real)DIM);
            ext = j == 0 ? hi[j] - lo[j] : fmax(ext, hi[j] - lo[j]);
        }
        const real grow = bary2 * ext + margin;
        for (int j = 0; j < DIM; ++j) {
            a[j] = next_down(TO_FLOAT(lo[j] - grow));
            b[j] = next_up(TO_FLOAT(hi[j] + grow));
        }
        const float4 cen = vload4(0, m);
        rec[3 * (size_t)out] = vload4(0, a);
        rec[3 * (size_t)out + 1] = vload4(0, b);
        rec[3 * (size_t)out + 2] = cen;
        ids[out] = s;
        c_lo = fmin(c_lo, cen);
        c_hi = fmax(c_hi, cen);
        ++out;
    }
    part_c[2 * c] = c_lo;
    part_c[2 * c + 1] = c_hi;
}

// leaf blocks of the kernels' wide tree (ao4d.bvh.widen's layout (B, DIM + 1, DIM, lanes)):
// one work-item per block lane (neighbouring work-items write neighbouring floats); lanes past
// a block's count are zero
__kernel void fill_blocks(__global const real *vertices, __global const int *simplices,
                          __global const int *order, __global const int2 *block_range,
                          const int lanes, __global float *blocks)
{
    const int blk = get_global_id(0) / lanes, l = get_global_id(0) % lanes;
    const int2 range = block_range[blk];  // first tree-order simplex, count
    __global float *out = blocks + (size_t)blk * (DIM + 1) * DIM * lanes + l;
    if (l >= range.y) {
        for (int r = 0; r < (DIM + 1) * DIM; ++r) out[r * lanes] = 0.0f;
        return;
    }
    real p[DIM][DIM], e[DIM][DIM], n[DIM], nn, inv[DIM][DIM];
    load_corners(vertices, simplices, order[range.x + l], p);
    simplex_frame(p, e, n, &nn);
    simplex_inverse(e, n, nn, inv);
    for (int i = 0; i < DIM; ++i)
        for (int j = 0; j < DIM; ++j) out[(i * DIM + j) * lanes] = TO_FLOAT(inv[i][j]);
    for (int j = 0; j < DIM; ++j) out[(DIM * DIM + j) * lanes] = TO_FLOAT(p[0][j]);
}

// -- binned SAH ----------------------------------------------------------------------------------

inline float component(const float4 v, const int k)
{
    return k == 0 ? v.x : k == 1 ? v.y : k == 2 ? v.z : v.w;
}

// the host's bin of a centroid coordinate: min(int(clip((v - lo) / ext, 0, 1) * bins), bins - 1)
// (ext = inf for a node whose centroids are flat along the axis: every primitive in bin 0)
inline int bin_of_value(const float v, const float lo, const float ext, const int bins)
{
    const float frac = fmin(fmax((v - lo) / ext, 0.0f), 1.0f);
    return min((int)(frac * (float)bins), bins - 1);
}

// boundary (d-1)-measure of a box (ao4d.bvh._box_area)
inline float box_area(const float4 lo, const float4 hi)
{
    const float4 e = fmax(hi - lo, (float4)(0.0f));
#if DIM == 2
    return 2.0f * (e.x + e.y);
#elif DIM == 3
    return 2.0f * (e.x * (e.y + e.z) + e.y * e.z);
#else
    return 2.0f * (e.x * e.y * (e.z + e.w) + e.z * e.w * (e.x + e.y));
#endif
}

// per-bin primitive counts and box bounds: all the SAH needs (every binning kernel's bins)
typedef struct {
    int n[MAX_BINS];
    float4 lo[MAX_BINS], hi[MAX_BINS];
} BoxBins;

// empty the first `bins` bins
inline void bins_clear(BoxBins *b, const int bins)
{
    for (int k = 0; k < bins; ++k) {
        b->n[k] = 0;
        b->lo[k] = (float4)(INFINITY);
        b->hi[k] = (float4)(-INFINITY);
    }
}

// bin k takes n primitives whose boxes span [lo, hi]
inline void bins_add(BoxBins *b, const int k, const int n, const float4 lo, const float4 hi)
{
    b->n[k] += n;
    b->lo[k] = fmin(b->lo[k], lo);
    b->hi[k] = fmax(b->hi[k], hi);
}

// the SAH split of the first `bins` bins: returns the first bin of the right side (0: none) and
// the node's box
inline int sah_split(const BoxBins *b, const int bins, float4 *box_lo, float4 *box_hi)
{
    float4 run_lo[MAX_BINS], run_hi[MAX_BINS];  // suffix unions of the boxes
    float4 lo = (float4)(INFINITY), hi = (float4)(-INFINITY);
    for (int k = bins - 1; k >= 0; --k) {
        lo = fmin(lo, b->lo[k]);
        hi = fmax(hi, b->hi[k]);
        run_lo[k] = lo;
        run_hi[k] = hi;
    }
    *box_lo = lo;
    *box_hi = hi;
    int total = 0;
    for (int k = 0; k < bins; ++k) total += b->n[k];
    int best = 0, left_n = 0;
    float best_cost = INFINITY;
    lo = (float4)(INFINITY);
    hi = (float4)(-INFINITY);
    for (int k = 0; k < bins - 1; ++k) {
        left_n += b->n[k];
        lo = fmin(lo, b->lo[k]);
        hi = fmax(hi, b->hi[k]);
        const int right_n = total - left_n;
        if (left_n == 0 || right_n == 0) continue;
        const float cost = box_area(lo, hi) * (float)left_n + box_area(run_lo[k + 1], run_hi[k + 1]) * (float)right_n;
        if (cost < best_cost) {
            best_cost = cost;
            best = k + 1;
        }
    }
    return best;
}

inline int longest_axis(const float4 lo, const float4 hi, float *start, float *ext)
{
    float e[4], l[4];
    vstore4(hi - lo, 0, e);
    vstore4(lo, 0, l);
    int axis = 0;
    for (int k = 1; k < DIM; ++k)
        if (e[k] > e[axis]) axis = k;  // first of equal extents, like numpy's argmax
    *start = l[axis];
    *ext = e[axis] > 0.0f ? e[axis] : INFINITY;
    return axis;
}

inline int bins_for(const int count) { return count > 8 * MAX_BINS ? MAX_BINS : MAX_BINS / 2; }

// -- large nodes: one level at a time over chunks of their primitives ------------------------------
// level tables: node_i[n] = (axis, bins, start, count), node_f[n] = (bin origin, extent, 0, 0),
// node_c[2 n], node_c[2 n + 1] = centroid bounds, node_chunk[n] .. node_chunk[n + 1] its chunks;
// chunk_i[c] = (node, begin, end, 0)

__kernel __attribute__((vec_type_hint(float4))) void bin_chunks(
    __global const float4 *rec, __global const int4 *chunk_i, __global const int4 *node_i,
    __global const float4 *node_f, __global uchar *bin_of, __global int *part_n,
    __global float4 *part_b)
{
    const int c = get_global_id(0);
    const int4 ch = chunk_i[c];
    const int4 ni = node_i[ch.x];
    const float4 nf = node_f[ch.x];
    BoxBins b;
    bins_clear(&b, MAX_BINS);
    for (int i = ch.y; i < ch.z; ++i) {
        const int k = bin_of_value(component(rec[3 * (size_t)i + 2], ni.x), nf.x, nf.y, ni.y);
        bin_of[i] = (uchar)k;
        bins_add(&b, k, 1, rec[3 * (size_t)i], rec[3 * (size_t)i + 1]);
    }
    for (int k = 0; k < MAX_BINS; ++k) {
        const size_t at = (size_t)c * MAX_BINS + k;
        part_n[at] = b.n[k];
        part_b[2 * at] = b.lo[k];
        part_b[2 * at + 1] = b.hi[k];
    }
}

// one work-item per node: reduce the chunks' bins, choose the split, give each chunk its left
// and right write positions. res_i[n] = (first right bin or -1 for "first half / second half",
// left count, 0, 0); res_f[6 n ..] = box low, high and, for halves only, the children's
// centroid bounds (the parent's); after an SAH split scatter_chunks gives them per chunk.
__kernel void split_nodes(__global const int4 *node_i, __global const float4 *node_c,
                          __global const int *node_chunk, __global const int4 *chunk_i,
                          __global const int *part_n, __global const float4 *part_b,
                          const int level, __global int4 *res_i, __global float4 *res_f,
                          __global int2 *chunk_off)
{
    const int n = get_global_id(0);
    const int4 ni = node_i[n];
    const int c0 = node_chunk[n], c1 = node_chunk[n + 1];
    BoxBins b;
    bins_clear(&b, MAX_BINS);
    for (int c = c0; c < c1; ++c)
        for (int k = 0; k < ni.y; ++k) {
            const size_t at = (size_t)c * MAX_BINS + k;
            bins_add(&b, k, part_n[at], part_b[2 * at], part_b[2 * at + 1]);
        }
    float4 lo, hi;
    int split = sah_split(&b, ni.y, &lo, &hi);
    if (level >= SAH_MAX_LEVEL) split = 0;
    int left = 0;
    float4 c_lo = (float4)(INFINITY), c_hi = (float4)(-INFINITY);
    if (split > 0) {
        for (int k = 0; k < split; ++k) left += b.n[k];
        int l_at = ni.z, r_at = ni.z + left;
        for (int c = c0; c < c1; ++c) {
            int l = 0;
            for (int k = 0; k < split; ++k) l += part_n[(size_t)c * MAX_BINS + k];
            chunk_off[c] = (int2)(l_at, r_at);
            l_at += l;
            r_at += chunk_i[c].z - chunk_i[c].y - l;
        }
    } else {  // no SAH split (flat centroids) or too deep: halves in the current order
        split = -1;
        left = ni.w / 2;
        c_lo = node_c[2 * n];
        c_hi = node_c[2 * n + 1];
        for (int c = c0; c < c1; ++c) chunk_off[c] = (int2)(chunk_i[c].y, -1);
    }
    res_i[n] = (int4)(split, left, 0, 0);
    res_f[6 * n] = lo;
    res_f[6 * n + 1] = hi;
    res_f[6 * n + 2] = res_f[6 * n + 4] = c_lo;
    res_f[6 * n + 3] = res_f[6 * n + 5] = c_hi;
}

// stable partition of each chunk: left primitives to their node's front, right ones after;
// part_c[4 c ..] = the chunk's left and right centroid bounds (low, high, low, high), which
// the host reduces per node: the same min / max as bins of centroids, the same bits
__kernel __attribute__((vec_type_hint(float4))) void scatter_chunks(
    __global const float4 *src, __global const int *src_ids, __global float4 *dst,
    __global int *dst_ids, __global const int4 *chunk_i, __global const int4 *res_i,
    __global const uchar *bin_of, __global const int2 *chunk_off, __global float4 *part_c)
{
    const int c = get_global_id(0);
    const int4 ch = chunk_i[c];
    const int split = res_i[ch.x].x;
    int2 at = chunk_off[c];
    float4 l_lo = (float4)(INFINITY), l_hi = (float4)(-INFINITY), r_lo = l_lo, r_hi = l_hi;
    for (int i = ch.y; i < ch.z; ++i) {
        const float4 cen = src[3 * (size_t)i + 2];
        int j;
        if (split < 0) {
            j = i;
        } else if (bin_of[i] < split) {
            j = at.x++;
            l_lo = fmin(l_lo, cen);
            l_hi = fmax(l_hi, cen);
        } else {
            j = at.y++;
            r_lo = fmin(r_lo, cen);
            r_hi = fmax(r_hi, cen);
        }
        dst[3 * (size_t)j] = src[3 * (size_t)i];
        dst[3 * (size_t)j + 1] = src[3 * (size_t)i + 1];
        dst[3 * (size_t)j + 2] = cen;
        dst_ids[j] = src_ids[i];
    }
    part_c[4 * c] = l_lo;
    part_c[4 * c + 1] = l_hi;
    part_c[4 * c + 2] = r_lo;
    part_c[4 * c + 3] = r_hi;
}

// -- small nodes: one work-item builds a whole subtree -------------------------------------------

inline void reduce_range(__global const float4 *rec, const int start, const int count, const int row,
                         float4 *lo, float4 *hi)
{
    float4 a = (float4)(INFINITY), z = (float4)(-INFINITY);
    for (int i = start; i < start + count; ++i) {
        if (row == 2) {
            a = fmin(a, rec[3 * (size_t)i + 2]);
            z = fmax(z, rec[3 * (size_t)i + 2]);
        } else {
            a = fmin(a, rec[3 * (size_t)i]);
            z = fmax(z, rec[3 * (size_t)i + 1]);
        }
    }
    *lo = a;
    *hi = z;
}

inline void move_record(__global float4 *src, __global int *src_ids, const int i,
                        __global float4 *dst, __global int *dst_ids, const int j)
{
    dst[3 * (size_t)j] = src[3 * (size_t)i];
    dst[3 * (size_t)j + 1] = src[3 * (size_t)i + 1];
    dst[3 * (size_t)j + 2] = src[3 * (size_t)i + 2];
    dst_ids[j] = src_ids[i];
}

// tasks[t] = (node id, start, count, level + 256 * (data in the second buffer)),
// task_c[2 t], task_c[2 t + 1] = centroid bounds. Writes meta (left, right) or
// (-(start + 1), count), node bounds, and the simplices in tree order. A subtree owns its range
// in both buffers: partitions go from one to the other (children remember where their data is).
__kernel __attribute__((vec_type_hint(float4))) void build_subtrees(
    __global float4 *rec_a, __global int *ids_a, __global float4 *rec_b, __global int *ids_b,
    __global uchar *bin_of, __global const int4 *tasks, __global const float4 *task_c,
    const int leaf_size, __global int *counter, __global int2 *meta, __global float4 *node_lo,
    __global float4 *node_hi, __global int *order)
{
    const int4 task = tasks[get_global_id(0)];
    int4 stack[SUBTREE_STACK];  // (id, start, count, level + 256 * buffer)
    float4 stack_c[2 * SUBTREE_STACK];
    stack[0] = task;
    stack_c[0] = task_c[2 * get_global_id(0)];
    stack_c[1] = task_c[2 * get_global_id(0) + 1];
    int sp = 1;
    BoxBins b;
    while (sp > 0) {
        --sp;
        const int4 nd = stack[sp];
        const float4 c_lo = stack_c[2 * sp], c_hi = stack_c[2 * sp + 1];
        const int id = nd.x, start = nd.y, count = nd.z, level = nd.w & 255, second = nd.w >> 8;
        __global float4 *rec = second ? rec_b : rec_a;
        __global int *ids = second ? ids_b : ids_a;
        __global float4 *tmp = second ? rec_a : rec_b;
        __global int *tmp_ids = second ? ids_a : ids_b;
        float4 lo, hi, cb[4];
        if (count <= leaf_size) {
            reduce_range(rec, start, count, 0, &lo, &hi);
            node_lo[id] = lo;
            node_hi[id] = hi;
            meta[id] = (int2)(-(start + 1), count);
            for (int i = start; i < start + count; ++i) order[i] = ids[i];
            continue;
        }
        float origin, ext;
        const int axis = longest_axis(c_lo, c_hi, &origin, &ext);
        int left, moved = 0;
        if (count <= SAH_MIN_COUNT) {
            // median of the centroids along the axis: insertion sort of at most 16 records
            for (int i = start + 1; i < start + count; ++i) {
                const float v = component(rec[3 * (size_t)i + 2], axis);
                int j = i;
                while (j > start && component(rec[3 * (size_t)(j - 1) + 2], axis) > v) --j;
                if (j == i) continue;
                move_record(rec, ids, i, tmp, tmp_ids, i);  // park record i
                for (int k = i; k > j; --k) move_record(rec, ids, k - 1, rec, ids, k);
                move_record(tmp, tmp_ids, i, rec, ids, j);
            }
            const int mid = count / 2;
            left = clamp(leaf_size * (int)rint((float)mid / (float)leaf_size), leaf_size, count - 1);
            reduce_range(rec, start, count, 0, &lo, &hi);
            reduce_range(rec, start, left, 2, &cb[0], &cb[1]);
            reduce_range(rec, start + left, count - left, 2, &cb[2], &cb[3]);
        } else {
            // bins hold counts and boxes only; the sides' centroid bounds come from the
            // partition pass, which reads every centroid anyway (the same min / max, the same bits)
            const int bins = bins_for(count);
            bins_clear(&b, bins);
            for (int i = start; i < start + count; ++i) {
                const int k = bin_of_value(component(rec[3 * (size_t)i + 2], axis), origin, ext, bins);
                bin_of[i] = (uchar)k;
                bins_add(&b, k, 1, rec[3 * (size_t)i], rec[3 * (size_t)i + 1]);
            }
            int split = sah_split(&b, bins, &lo, &hi);
            if (level >= SAH_MAX_LEVEL) split = 0;
            if (split > 0) {
                left = 0;
                for (int k = 0; k < split; ++k) left += b.n[k];
                int l_at = start, r_at = start + left;
                float4 l_lo = (float4)(INFINITY), l_hi = (float4)(-INFINITY), r_lo = l_lo, r_hi = l_hi;
                for (int i = start; i < start + count; ++i) {
                    const float4 cen = rec[3 * (size_t)i + 2];
                    if (bin_of[i] < split) {
                        l_lo = fmin(l_lo, cen);
                        l_hi = fmax(l_hi, cen);
                        move_record(rec, ids, i, tmp, tmp_ids, l_at++);
                    } else {
                        r_lo = fmin(r_lo, cen);
                        r_hi = fmax(r_hi, cen);
                        move_record(rec, ids, i, tmp, tmp_ids, r_at++);
                    }
                }
                cb[0] = l_lo;
                cb[1] = l_hi;
                cb[2] = r_lo;
                cb[3] = r_hi;
                moved = 1;
            } else {
                left = count / 2;
                cb[0] = cb[2] = c_lo;
                cb[1] = cb[3] = c_hi;
            }
        }
        node_lo[id] = lo;
        node_hi[id] = hi;
        if (sp + 2 > SUBTREE_STACK) {  // cannot happen for subtrees of the host's sizes
            atomic_or(counter + 1, 1);
            meta[id] = (int2)(-(start + 1), count);
            continue;
        }
        const int child = atomic_add(counter, 2);
        meta[id] = (int2)(child, child + 1);
        const int where = 256 * (second ^ moved) + level + 1;
        // right pushed first: the left child is built next (depth first, stack <= depth + 1)
        stack[sp] = (int4)(child + 1, start + left, count - left, where);
        stack_c[2 * sp] = cb[2];
        stack_c[2 * sp + 1] = cb[3];
        ++sp;
        stack[sp] = (int4)(child, start, left, where);
        stack_c[2 * sp] = cb[0];
        stack_c[2 * sp + 1] = cb[1];
        ++sp;
    }
}
