// Traversal of the WIDTH-wide BVH built by ao4d/bvh.py (widen; WIDTH = 8 by default): node k
// has its children's boxes at boxes[k * 2 * DIM ...] (one vector lane per child) and
// children[WIDTH k + s]: a node index > 0, 0 for none, or -(1 + 4 b + m - 1) for the m
// consecutive leaf blocks from block b.
// Hits are reported as LANES * block + lane.
#ifndef AO4D_BVH_H
#define AO4D_BVH_H

#include "common/geometry.h"

// traversal stack entries: ao4d.bvh.STACK_SIZE, passed by the host, which refuses trees with
// depth * (WIDTH - 1) + 1 > STACK_SIZE (a node visit pops one entry and pushes at most WIDTH)
#ifndef STACK_SIZE
#error "compile with -D STACK_SIZE=n (ao4d.bvh.STACK_SIZE)"
#endif

// -D COUNT_VISITS builds a debug variant whose any-hit traversal also counts the wide nodes it
// visits (visits[0]) and the leaf blocks it tests (visits[1]); callers pass `visits` along
// (ao4d.rays.api.traversal_counts). Without it the macros vanish.
// The packet traversal (trace_packet) also counts the ray-node box tests (visits[2]) and the
// ray-block tests (visits[3]); for the one-ray traversal these equal visits[0] and visits[1].
#ifdef COUNT_VISITS
#define VISITS_PARAM , int *visits
#define VISITS_ARG , visits
#define VISITS_DECL int visits[4] = {0, 0, 0, 0};
#define COUNT_VISIT(k) (visits[k] += 1)
#else
#define VISITS_PARAM
#define VISITS_ARG
#define VISITS_DECL
#define COUNT_VISIT(k)
#endif

// a ray's coordinates and its box-test constants (see hit_boxes)
typedef struct {
    float o[DIM], w[DIM], inv_w[DIM], o_inv[DIM];
    int near[DIM], far[DIM];
} Ray;

inline void load_ray(const float4 o4, const float4 w4, Ray *r)
{
    float a[4], b[4];
    vstore4(o4, 0, a);
    vstore4(w4, 0, b);
    for (int j = 0; j < DIM; ++j) {
        r->o[j] = a[j];
        r->w[j] = b[j];
        // a zero component gives a huge finite inverse, not inf: the box test then never meets
        // 0 * inf = NaN and can use plain min / max (see hit_boxes). The stand-in for zero
        // scales with |o| so that o * inv_w stays finite (at most 2^100): 1e-30 alone overflowed
        // float32 for |o| > 3.4e8 and rejected boxes the ray meets. fma(box, inv_w, -o_inv) is
        // then finite or an overflow with the right sign; the slab error stays |o| 2^-24 in
        // coordinates, which the boxes' margin covers as for any other direction.
        const float tiny = fmax(1e-30f, fabs(a[j]) * 0x1p-100f);
        r->inv_w[j] = 1.0f / (fabs(b[j]) > tiny ? b[j] : copysign(tiny, b[j]));
        r->o_inv[j] = a[j] * r->inv_w[j];
        const int negative = signbit(r->inv_w[j]) != 0;
        r->near[j] = negative ? DIM + j : j;
        r->far[j] = negative ? j : DIM + j;
    }
}

// any hit with 0 < t <= t_max (occlusion rays) in the subtree of `node`, for the ray from o with
// direction w and box-test constants near / far / inv_w / o_inv (load_ray's): LANES * block +
// lane, or -1 (t_out: its t, else t_max). The children of a node are pushed in slot order, not
// nearest first; a ray that hits nothing must visit every box it meets anyway, and AO rays
// mostly escape. No distances on the stack: t_max never shrinks before the return.
inline int walk_any(__global const floatW *boxes, __global const int *children,
                    __global const floatL *blocks, const float *o, const float *w, const int *near,
                    const int *far, const float *inv_w, const float *o_inv, int node,
                    const float t_max, float *t_out VISITS_PARAM)
{
    int stack[STACK_SIZE];
    int sp = 0;
    for (;;) {
        COUNT_VISIT(0);
        COUNT_VISIT(2);
        __global const int *child = children + (size_t)node * WIDTH;
        floatW tnw;
        const intW hitw = hit_boxes(boxes + (size_t)node * 2 * DIM, near, far, inv_w, o_inv, t_max, &tnw);
        // the slots the ray's box test hit that hold a child, in slot order
        for (int slots = lane_bits(hitw & (vloadW(0, child) != (intW)(0))); slots; slots &= slots - 1) {
            const int c = child[31 - (int)clz(slots & -slots)];
            if (c > 0) {
                stack[sp++] = c;
                continue;
            }
            const int first = (-c - 1) >> 2;
            const int end = first + ((-c - 1) & 3) + 1;
            for (int b = first; b < end; ++b) {
                float t;
                COUNT_VISIT(1);
                COUNT_VISIT(3);
                const int lane = hit_block(blocks + (size_t)b * BLOCK_ROWS, o, w, t_max, &t);
                if (lane >= 0) {
                    *t_out = t;
                    return LANES * b + lane;
                }
            }
        }
        if (sp == 0) break;
        node = stack[--sp];
    }
    *t_out = t_max;
    return -1;
}

// walk_any from the root for one ray
inline int trace_any(__global const floatW *boxes, __global const int *children,
                     __global const floatL *blocks, const float4 o4, const float4 w4,
                     const float t_max, float *t_out VISITS_PARAM)
{
    Ray ray;
    load_ray(o4, w4, &ray);
    return walk_any(boxes, children, blocks, ray.o, ray.w, ray.near, ray.far, ray.inv_w, ray.o_inv, 0,
                    t_max, t_out VISITS_ARG);
}

// -- shared-origin packets (ambient occlusion) ------------------------------------------------
// trace_packet traces up to PACKET rays from one origin together: a node is fetched once per
// packet and its child boxes tested for every ray still in its mask; a child is pushed with the
// mask of the rays that hit its box; a ray that hits a leaf simplex retires from every mask. A
// ray's tests are trace_any's, with the same arithmetic: a ray without a hit tests exactly the
// boxes and blocks trace_any tests, and a ray retires only on a hit trace_any would accept, so
// the hit / miss answer is the same; the visit order only changes which tests a ray makes before
// its first hit. The nodes around the origin, which every ray of a point visits, are fetched and
// walked once, not once per ray. The children a node pushes are sorted so that the box nearest
// the shared origin is popped first: near boxes hold the occluders most rays hit, so rays retire
// before the far subtrees are fetched (measured on the dense shapes: 11-15 % fewer node fetches,
// about 10 % less trace time; on the tiger and the spheritorus no change beyond the noise).
// A popped node that at most PACKET_SPLIT rays still need is walked by each of them alone
// (walk_any from that node): deep in the tree the packet's masks, sorted pushes and shared block
// origins cost more than they share (metaballs, one core, interleaved with the packet-only
// kernel: 0.95x the trace time at 2, 0.93-0.98x at 4, 0.99x at 8, 1.07x at 32; the same counts).
#ifndef PACKET
#define PACKET 32
#endif
// -D PACKET_HITS (kernels/rays/cast_packets.cl): trace_packet also records, per ray, the hit that
// retired it (LANES * block + lane, the answer trace_any gives for some hit) in hit_of[r]
#ifdef PACKET_HITS
#define HITS_PARAM , int *hit_of
#define RECORD_HIT(r, h) (hit_of[r] = (h))
#else
#define HITS_PARAM
#define RECORD_HIT(r, h)
#endif
#ifndef PACKET_SPLIT
#define PACKET_SPLIT 2
#endif
#if PACKET == 32
#define pmask uint
#if WIDTH == 8
#define pmaskW uint8
#define MASKW(h) as_uint8(h)
#else
#define pmaskW uint16
#define MASKW(h) as_uint16(h)
#endif
#elif PACKET == 64
#define pmask ulong
#if WIDTH == 8
#define pmaskW ulong8
#define MASKW(h) as_ulong8(convert_long8(h))
#else
#define pmaskW ulong16
#define MASKW(h) as_ulong16(convert_long16(h))
#endif
#else
#error "PACKET must be 32 or 64"
#endif

// a packet ray: its direction and box-test constants (the shared origin is kept once)
typedef struct {
    float w[DIM], inv_w[DIM], o_inv[DIM];
    int near[DIM], far[DIM];
} PacketRay;

// rays[k0 .. k0 + count) of a packet from origin o and the coordinates w[j] of eight directions
// (cosine_directions8): load_ray's arithmetic on eight rays at once, the same bits
inline void load_packet_rays8(const float *o, const float8 *w, const int count, PacketRay *rays)
{
    float wj[8], inv[8], o_inv[8];
    int negative[8];
    for (int j = 0; j < DIM; ++j) {
        const float tiny = fmax(1e-30f, fabs(o[j]) * 0x1p-100f);  // see load_ray
        const float8 inv_w = 1.0f / select(copysign((float8)(tiny), w[j]), w[j],
                                           isgreater(fabs(w[j]), (float8)(tiny)));
        vstore8(w[j], 0, wj);
        vstore8(inv_w, 0, inv);
        vstore8(o[j] * inv_w, 0, o_inv);
        vstore8(signbit(inv_w), 0, negative);
        for (int k = 0; k < count; ++k) {
            rays[k].w[j] = wj[k];
            rays[k].inv_w[j] = inv[k];
            rays[k].o_inv[j] = o_inv[k];
            rays[k].near[j] = negative[k] ? DIM + j : j;
            rays[k].far[j] = negative[k] ? j : DIM + j;
        }
    }
}

// index of the lowest set bit of m != 0 (OpenCL C 1.2 has clz, not ctz)
inline int lowest_ray(const pmask m)
{
    return (int)(8 * sizeof(pmask) - 1) - (int)clz(m & (~m + 1));
}

// the rays of `active` (bit r: rays[r]) that hit something with 0 < t <= t_max from origin o
inline pmask trace_packet(__global const floatW *boxes, __global const int *children,
                          __global const floatL *blocks, const float *o, const PacketRay *rays,
                          const pmask active, const float t_max HITS_PARAM VISITS_PARAM)
{
    pmask alive = active;  // rays without a hit so far
    int stack[STACK_SIZE];
    pmask stack_mask[STACK_SIZE];
    float stack_key[STACK_SIZE];  // squared distance from o to the pushed node's box
    int sp = 0;
    int node = 0;
    pmask mask = active;
    for (;;) {
        COUNT_VISIT(0);
        __global const floatW *box = boxes + (size_t)node * 2 * DIM;
        pmaskW child_mask = (pmaskW)(0);
        for (pmask left = mask; left; left &= left - 1) {
            const int r = lowest_ray(left);
            floatW tnw;
            COUNT_VISIT(2);
            const intW h = hit_boxes(box, rays[r].near, rays[r].far, rays[r].inv_w, rays[r].o_inv,
                                     t_max, &tnw);
            child_mask |= MASKW(h) & (pmaskW)((pmask)1 << r);
        }
        pmask masks[WIDTH];
        vstoreW(child_mask, 0, masks);
        __global const int *child = children + (size_t)node * WIDTH;
        float key[WIDTH];  // squared distance from o to each child box: one vector op per axis
        {
            floatW d2 = (floatW)(0.0f);
            for (int j = 0; j < DIM; ++j) {
                const floatW gap = fmax(fmax(box[j] - o[j], o[j] - box[DIM + j]), (floatW)(0.0f));
                d2 += gap * gap;
            }
            vstoreW(d2, 0, key);
        }
        const int base = sp;  // this node's children are sorted among themselves only
        // the slots some ray hits, in slot order: a node has few such children of WIDTH
        int slots = lane_bits(convert_intW(child_mask != (pmaskW)(0)) & (vloadW(0, child) != (intW)(0)));
        for (; slots; slots &= slots - 1) {
            const int s = 31 - (int)clz(slots & -slots);
            const int c = child[s];
            if (c > 0) {
                int k = sp++;  // insertion: the nearest child ends on top of the stack
                while (k > base && key[s] > stack_key[k - 1]) {
                    stack_key[k] = stack_key[k - 1];
                    stack[k] = stack[k - 1];
                    stack_mask[k] = stack_mask[k - 1];
                    --k;
                }
                stack_key[k] = key[s];
                stack[k] = c;
                stack_mask[k] = masks[s];
                continue;
            }
            const int first = (-c - 1) >> 2;
            const int end = first + ((-c - 1) & 3) + 1;
            for (int b = first; b < end; ++b) {
                pmask left = masks[s] & alive;
                if (!left) break;
                COUNT_VISIT(1);
                __global const floatL *blk = blocks + (size_t)b * BLOCK_ROWS;
                floatL rel[DIM];
                const floatL q = block_origin(blk, o, rel);  // shared by the packet's rays
                for (; left; left &= left - 1) {
                    const int r = lowest_ray(left);
                    float t;
                    COUNT_VISIT(3);
                    const int lane = hit_block_at(blk, rel, q, rays[r].w, t_max, &t);
                    if (lane >= 0) {
                        alive &= ~((pmask)1 << r);
                        RECORD_HIT(r, LANES * b + lane);
                    }
                }
            }
            if (!alive) return active;
        }
        // the next node some ray without a hit still has to visit
        for (;;) {
            if (sp == 0) return active & ~alive;
            --sp;
            mask = stack_mask[sp] & alive;
            if (mask && popcount(mask) <= PACKET_SPLIT) {  // a few rays: each on its own
                for (pmask left = mask; left; left &= left - 1) {
                    const int r = lowest_ray(left);
                    float t;
                    const int h = walk_any(boxes, children, blocks, o, rays[r].w, rays[r].near,
                                           rays[r].far, rays[r].inv_w, rays[r].o_inv, stack[sp],
                                           t_max, &t VISITS_ARG);
                    if (h >= 0) {
                        alive &= ~((pmask)1 << r);
                        RECORD_HIT(r, h);
                    }
                }
                if (!alive) return active;
                continue;
            }
            if (mask) break;
        }
        node = stack[sp];
    }
}

// the closest hit with 0 < t <= t_max: LANES * block + lane, or -1 (t_out: its t, else t_max)
inline int trace_closest(__global const floatW *boxes, __global const int *children,
                     __global const floatL *blocks, const float4 o4, const float4 w4,
                     float t_max, float *t_out)
{
    Ray ray;
    load_ray(o4, w4, &ray);
    int stack[STACK_SIZE];
    float stack_t[STACK_SIZE];
    int sp = 0;
    int node = 0;
    int best = -1;
    for (;;) {
        floatW tnw;
        const intW hitw = hit_boxes(boxes + (size_t)node * 2 * DIM, ray.near, ray.far, ray.inv_w,
                                    ray.o_inv, t_max, &tnw);
        if (any(hitw)) {
            int hits[WIDTH];
            float tn[WIDTH];
            vstoreW(hitw, 0, hits);
            vstoreW(tnw, 0, tn);
            __global const int *child = children + (size_t)node * WIDTH;
            const int base = sp;
            for (int s = 0; s < WIDTH; ++s) {
                const int c = child[s];
                if (!hits[s] || c == 0) continue;
                if (c > 0) {
                    // keep this node's pushes sorted by decreasing entry distance: the
                    // nearest child is popped first
                    int k = sp++;
                    while (k > base && stack_t[k - 1] < tn[s]) {
                        stack_t[k] = stack_t[k - 1];
                        stack[k] = stack[k - 1];
                        --k;
                    }
                    stack_t[k] = tn[s];
                    stack[k] = c;
                    continue;
                }
                // a leaf: blocks b .. b + m - 1 with -c - 1 = 4 b + m - 1
                const int first = (-c - 1) >> 2;
                const int end = first + ((-c - 1) & 3) + 1;
                for (int b = first; b < end; ++b) {
                    float t;
                    const int lane = hit_block(blocks + (size_t)b * BLOCK_ROWS, ray.o, ray.w, t_max, &t);
                    if (lane >= 0) {
                        best = LANES * b + lane;
                        t_max = t;
                    }
                }
            }
        }
        // next node whose box is still in reach
        node = -1;
        while (sp > 0) {
            --sp;
            if (stack_t[sp] <= t_max) {
                node = stack[sp];
                break;
            }
        }
        if (node < 0) break;
    }
    *t_out = t_max;
    return best;
}

// closest (any_hit = 0) or any (any_hit = 1) hit with 0 < t <= t_max: LANES * block + lane or -1
inline int trace_bvh(__global const floatW *boxes, __global const int *children,
                     __global const floatL *blocks, const float4 o4, const float4 w4,
                     float t_max, const int any_hit, float *t_out VISITS_PARAM)
{
    if (any_hit) return trace_any(boxes, children, blocks, o4, w4, t_max, t_out VISITS_ARG);
    return trace_closest(boxes, children, blocks, o4, w4, t_max, t_out);
}

// the same answer by testing every leaf block (for tests and the speed-up benchmark)
inline int trace_brute(__global const floatL *blocks, const int n_blocks, const float4 o4,
                       const float4 w4, float t_max, const int any_hit, float *t_out)
{
    Ray ray;
    load_ray(o4, w4, &ray);
    int best = -1;
    for (int b = 0; b < n_blocks; ++b) {
        float t;
        const int lane = hit_block(blocks + (size_t)b * BLOCK_ROWS, ray.o, ray.w, t_max, &t);
        if (lane >= 0) {
            best = LANES * b + lane;
            t_max = t;
            if (any_hit) break;
        }
    }
    *t_out = t_max;
    return best;
}

#endif
