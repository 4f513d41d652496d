// Probabilistic ray-casting gain (docs/method.md#probabilistic-ray-casting-gain) and view gain (docs/method.md#candidate-views-and-view-gain, equation (7)).
//
// The grid is one float per cell ("code", see opencl.py: march_grid), C order [x][y][z] (2D
// grids have nz = 1), padded with one known-occupied cell on every side (2D: on x and y only):
//   code >= 0   unknown cell, occupancy probability p = code
//   code == -1  known occupied (p = 1), also the padding
//   code <= -2  known empty (p = 0), d = -1 - code >= 1 is a lower bound of the Chebyshev
//               distance to the nearest non-empty cell (opencl.py: empty_distance)
// Sample t of ray h from origin v is the padded cell v + offsets[h][t], a linear index offset
// (precomputed from round(t * b_h)). Consecutive samples differ by at most one cell per axis
// (|b| <= 1), so samples t and t + k are at most k apart in the Chebyshev metric. Hence:
//   * a ray leaving the grid samples the occupied padding first and stops there, exactly as if
//     every cell outside the grid were known occupied: no bounds checks in the loop;
//   * samples 0 .. d - 1 of every ray from an origin at distance d are empty and change neither
//     H nor Pr (nor the information gain): view_gain starts the rays of a work-group at the
//     smallest d of its origins (first_sample). This is exact. (Jumping by d inside the loop is
//     exact too but was measured ~2x slower on a CPU: each read waits for the previous one; with
//     lanes all lanes step together anyway.)
//
// march_rays is the one implementation of the ray marching: one ray from LANES origins at once
// (LANES, a build option, 1 on a GPU; on a CPU 16: pocl compiles a work-item's loop to scalar
// code, where data-dependent branches per sample cost more than the march; as a vector of lanes
// the loop is branch-free up to "no lane alive", in float32 the same operations per lane as
// the scalar loop, hence bit-identical gains). ray_gain stores it per (origin, ray) (poses
// with their own frusta), view_gain sums it into the candidate views per origin.
//
// GAIN_ORIGINAL (a build option, default 0) selects the gain variant of gain/variant.py: 0 is the
// paper's (docs/method.md: gain, candidate views); 1 the host choices of the authors' code (docs/original_code.md), with
// the same marching: weights min((t / ORIGINAL_FOCAL)^nu, 1) (the host gives the shorter range
// as n_samples), MODE_PROBABILISTIC_FREE (an unknown sample counts (1 - p) Pr), per ray
// hits and hits + miss (`totals`; total_weight = the sum of all weights for the probabilistic
// modes), view gains sum(hits) / sum(totals), and the original ig (see march_rays). With 0 the
// preprocessed kernels are the paper's alone.
//
// Two more build options of the paper's variant (gain/sampling.py, docs/sensing.md; both 0 by
// default, when the preprocessed kernels are the paper's alone):
// GAIN_EXACT = 1: the rays' samples are the cells of their exact voxel traversal (the host's
// table from the simulator's traversal): each ray marches its own number of samples
// (ray_samples), sample t weighs sample_weights[h][t], and the minimum range is a per-ray first
// sample (ray_first_return). Each step still moves one cell along one axis, so the properties
// above (padding, first_sample) hold.
// GAIN_SENSOR = 1, the "returns" sensor model (mode prob): an unknown sample t counts w_t times
// the probability that the sensor measures it, sum_{j >= t} q_j with q_j = Pr(r_j) p_j g_j for the
// samples j at or beyond the minimum range (the table ends at the maximum range), g_j = 0 where
// the surface normal (normals: three planes of the marched grid) meets the ray at more than the
// grazing angle. In one pass: H = Q B - C with B = sum_t u_t w_t, S(t) = sum_{j < t} q_j,
// C = sum_t u_t w_t S(t) and Q = S at the end. Samples past weighted_samples only carry returns.
// A padding code in (-2, -1) (the grid border without walls) stops a ray without a return.
//
// The surface blend `surface` (beta in [0, 1], the paper's variant, mode prob; docs/method.md#surface-gain):
// an unknown sample counts ((1 - beta) + beta p) times its term of the paper's gain, w_t Pr(r_t):
// beta = 1 gives sum_t u_t w_t Pr(r_t) p_t, the expected (weighted) number of unknown cells where
// the ray's return lands. With GAIN_SENSOR the surface term is sum_t u_t w_t q_t (the return
// measured at t) and the blend mixes it with the sensor model's gain. beta = 0 multiplies by exactly
// 1 (resp. adds exactly 0): the paper's gains, bit for bit.
// SURFACE_BOUND = 1 (a build option, the coarse-to-fine bounds of a blend; the paper's variant
// without the sensor model): the code holds the smallest p of each window and the grid
// `surface_bound` (opencl.py: search_bounds) the largest p of its unknown cells; the bound is the
// ray's largest gain over every p in that range, found backwards after the march (see the end of
// march_rays). Taking the largest p for the factor and the smallest for the visibility apart is a
// bound too, but a loose one (docs/method.md#surface-gain).
#pragma OPENCL FP_CONTRACT OFF

#define MODE_PROBABILISTIC 0
#define MODE_INFORMATION_GAIN 1
#define MODE_PROBABILISTIC_FREE 2

#ifndef GAIN_ORIGINAL
#define GAIN_ORIGINAL 0
#endif
#ifndef ORIGINAL_FOCAL
#define ORIGINAL_FOCAL 8.0f
#endif
#ifndef ORIGINAL_NEAR_HIT
#define ORIGINAL_NEAR_HIT 0.01f
#endif
#ifndef ORIGINAL_BORDER
#define ORIGINAL_BORDER -1.25f
#endif

#ifndef LANES
#define LANES 1
#endif
#ifndef GAIN_EXACT
#define GAIN_EXACT 0
#endif
#ifndef GAIN_SENSOR
#define GAIN_SENSOR 0
#endif
#ifndef SURFACE_BOUND
#define SURFACE_BOUND 0
#endif
// DP_SAMPLES > 0 (with SURFACE_BOUND): the samples per ray of the launch; the march keeps each
// sample's window range [lo, hi] in private arrays for the backward pass, which then reads no grid
// (0: the backward pass gathers them again).
#ifndef DP_SAMPLES
#define DP_SAMPLES 0
#endif
#if SURFACE_BOUND && (GAIN_ORIGINAL || GAIN_SENSOR)
#error "SURFACE_BOUND is a bound of the paper's variant without the sensor model"
#endif
#if GAIN_ORIGINAL && (GAIN_EXACT || GAIN_SENSOR)
#error "GAIN_EXACT and GAIN_SENSOR are options of the paper's variant"
#endif

// The extra parameters of the two options: of the kernels (after their last parameter), of
// march_rays, and what a kernel passes for ray h.
#if GAIN_EXACT
#define EXACT_KERNEL_PARAMS , __global const float *sample_weights, __global const int *ray_samples, \
                              __global const int *ray_first_return
#define EXACT_MARCH_PARAMS , __global const float *weights_t, const int ray_end, const int first_return
#define EXACT_ARGS(h) , sample_weights + (size_t)(h) * n_samples, ray_samples[h], ray_first_return[h]
#define LOOP_END ray_end
#define WEIGHT(t) (weights_t[t])
#define AT_MIN_RANGE(t) ((t) >= first_return)
#else
#define EXACT_KERNEL_PARAMS
#define EXACT_MARCH_PARAMS
#define EXACT_ARGS(h)
#define LOOP_END n_samples
#define WEIGHT(t) ((nu == 1) ? (float)(t) : (float)((t) * (t)))
#define AT_MIN_RANGE(t) ((float)(t) >= min_range)
#endif
#if GAIN_SENSOR
#define SENSOR_KERNEL_PARAMS , __global const float *normals, const int n_cells, __global const float *directions, \
                               const float cos_grazing, const int weighted_samples
#define SENSOR_MARCH_PARAMS , __global const float *normals, const int n_cells, __global const float *direction, \
                              const float cos_grazing, const int weighted_samples
#define SENSOR_ARGS(h) , normals, n_cells, directions + 4 * (size_t)(h), cos_grazing, weighted_samples
#else
#define SENSOR_KERNEL_PARAMS
#define SENSOR_MARCH_PARAMS
#define SENSOR_ARGS(h)
#endif
#if SURFACE_BOUND
#define SURFACE_KERNEL_PARAMS , __global const float *surface_bound
#define SURFACE_ARGS , surface_bound
#define WINDOW_HI(cell) GATHER(surface_bound, cell)
#else
#define SURFACE_KERNEL_PARAMS
#define SURFACE_ARGS
#endif

// Lane vectors (floatv, intv) with aligned reads and writes (p: a multiple of LANES items from
// a buffer's start), gather and any-lane test. Macros, not functions: pocl has select() and
// any() out of line, its vload16 of int loses the kernels, and 16-wide vectors passed by value
// change the ABI without AVX-512 (a warning, and pocl's cached build of a program that warned
// lists no kernels).
#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)
#if LANES == 1
typedef float floatv;
typedef int intv;
#define GATHER(code, i) ((code)[i])
#define ANY_LANE(v) ((v) != 0)
#else
typedef CAT(float, LANES) floatv;
typedef CAT(int, LANES) intv;
#define GATHER CAT(GATHER, LANES)
#define ANY_LANE CAT(ANY, LANES)
#endif
#define LANES_AT(type, p) (*(type *)(p))
#define GATHER2(code, i) ((float2)((code)[(i).x], (code)[(i).y]))
#define GATHER4(code, i) ((float4)(GATHER2(code, (i).lo), GATHER2(code, (i).hi)))
#define GATHER8(code, i) ((float8)(GATHER4(code, (i).lo), GATHER4(code, (i).hi)))
#define GATHER16(code, i) ((float16)(GATHER8(code, (i).lo), GATHER8(code, (i).hi)))
#define ANY2(v) ((v).x | (v).y)
#define ANY4(v) ANY2((v).lo | (v).hi)
#define ANY8(v) ANY4((v).lo | (v).hi)
#define ANY16(v) ANY8((v).lo | (v).hi)

#if GAIN_ORIGINAL
// Weight of sample t in the original variant: min((t / f)^nu, 1).
inline float original_weight(const int t, const int nu)
{
    const float z = (float)t / ORIGINAL_FOCAL;
    return min((nu == 1) ? z : z * z, 1.0f);
}
#endif

// G_r of ray `off` from the origins of the LANES lanes (read at `origins`) into `gains`. A lane
// is alive until its ray stops (known occupied cell or grid border, or Pr <= eps, or for ig the
// first non-empty sample); dead lanes keep their values and read their origin cell.
// GAIN_ORIGINAL: `gains` gets the hits and `totals` hits + miss of each lane's ray (the paper
// build leaves `totals` alone). Original ig: the first non-empty sample t scores its weight if
// unknown and t >= min_range (ORIGINAL_NEAR_HIT below), nothing if occupied, and sets the total
// to the weights marched before it + 1; a ray that meets the grid border (padding code -1.5,
// above ORIGINAL_BORDER: outside the grid is empty to the original) or no non-empty sample keeps
// total_weight.
inline void march_rays(__global const float *code, __global const int *origins, __global const int *off,
                       const int first_sample, const int n_samples, const int nu, const float inv_total,
                       const float total_weight, const float eps, const int mode, const float min_range,
                       const float surface, floatv *gains, floatv *totals EXACT_MARCH_PARAMS SENSOR_MARCH_PARAMS
                       SURFACE_KERNEL_PARAMS)
{
    const intv origin = LANES_AT(__global const intv, origins);
    floatv visible = 1.0f;  // Pr(r_t) = prod_{i<t} (1 - p_i)
    floatv hit = 0.0f;      // H(v, h)
    intv alive = (intv)(-1);
#if GAIN_ORIGINAL
    floatv total = total_weight;  // hits + miss
    float marched = 0.0f;         // ig: the weights of the samples before t (all empty)
    if (mode == MODE_INFORMATION_GAIN) {
        for (int t = 0; t < first_sample; ++t) {
            marched += original_weight(t, nu);
        }
    }
#endif
#if GAIN_SENSOR
    floatv weighted = 0.0f;  // B
    floatv early = 0.0f;     // C
    floatv returned = 0.0f;  // S(t)
    floatv landed = 0.0f;    // sum_t u_t w_t q_t (the surface term)
    __global const float *normal_y = normals + n_cells;
    __global const float *normal_z = normal_y + n_cells;
#endif
#if SURFACE_BOUND
    intv end = (intv)(first_sample);  // per lane: one past the last sample it marched
    int marched_end = first_sample;  // the largest of them
#if DP_SAMPLES
    floatv window_lo[DP_SAMPLES], window_hi[DP_SAMPLES];  // per sample marched: code and surface_bound
#endif
#endif
    for (int t = first_sample; t < LOOP_END; ++t) {
        const intv cell = alive ? origin + off[t] : origin;
        const floatv c = GATHER(code, cell);
        const intv unknown = alive & (c >= 0.0f);
#if GAIN_ORIGINAL
        const float weight = original_weight(t, nu);
        if (mode == MODE_INFORMATION_GAIN) {
            const intv stops = alive & (c > -2.0f);
            hit = unknown ? (floatv)((float)t >= min_range ? weight : ORIGINAL_NEAR_HIT) : hit;
            total = (stops & (c > ORIGINAL_BORDER)) ? (floatv)(marched + 1.0f) : total;
            marched += weight;
            alive = alive & (c <= -2.0f);
        } else {
            const floatv seen = (mode == MODE_PROBABILISTIC_FREE) ? visible * (1.0f - c) : visible;
            hit = unknown ? hit + seen * weight : hit;
            visible = unknown ? visible * (1.0f - c) : visible;
            alive = alive & ((c <= -2.0f) | (unknown & (visible > eps)));
        }
#elif GAIN_SENSOR
        const float weight = t < weighted_samples ? WEIGHT(t) : 0.0f;
        if (mode == MODE_INFORMATION_GAIN) {
            hit = (unknown & (intv)(AT_MIN_RANGE(t) ? -1 : 0)) ? (floatv)(weight) : hit;
            alive = alive & (c <= -2.0f);
        } else {
            const intv occupied = alive & (c == -1.0f);
            const floatv p = unknown ? c : (occupied ? (floatv)(1.0f) : (floatv)(0.0f));
            weighted = unknown ? weighted + weight : weighted;
            early = unknown ? early + returned * weight : early;
            if (AT_MIN_RANGE(t)) {
                const floatv nx = GATHER(normals, cell), ny = GATHER(normal_y, cell), nz = GATHER(normal_z, cell);
                const floatv dot = nx * direction[0] + ny * direction[1] + nz * direction[2];
                const intv facing = ((nx * nx + ny * ny + nz * nz) == 0.0f) | (fabs(dot) >= cos_grazing);
                returned = facing ? returned + visible * p : returned;
                landed = (unknown & facing) ? landed + (visible * p) * weight : landed;
            }
            visible = visible * (1.0f - p);
            alive = alive & ((c <= -2.0f) | (unknown & (visible > eps)));
        }
#else
        const float weight = WEIGHT(t);
        if (mode == MODE_INFORMATION_GAIN) {
            hit = (unknown & (intv)(AT_MIN_RANGE(t) ? -1 : 0)) ? (floatv)(weight) : hit;
            alive = alive & (c <= -2.0f);  // stops at the first non-empty sample
        } else {
#if SURFACE_BOUND
            end = alive ? (intv)(t + 1) : end;
            marched_end = t + 1;
#if DP_SAMPLES
            window_lo[t] = c;
            window_hi[t] = WINDOW_HI(cell);
#endif
#else
            hit = unknown ? hit + visible * weight * ((1.0f - surface) + surface * c) : hit;
#endif
            visible = unknown ? visible * (1.0f - c) : visible;
            alive = alive & ((c <= -2.0f) | (unknown & (visible > eps)));  // occupied: Pr = 0 from here on
        }
#endif
        if (!ANY_LANE(alive)) {
            break;
        }
    }
#if SURFACE_BOUND
    // The block's bound of a blend: the largest sum_t u_t w_t Pr(r_t) ((1 - beta) + beta p_t) over
    // every choice of p_t in its window's range [lo_t, hi_t] (code: the smallest p, surface_bound:
    // the largest p of an unknown cell), by dynamic programming from the last sample marched to the
    // first: g_t = max over p in {lo_t, hi_t} of w_t ((1 - beta) + beta p) + (1 - p) g_{t+1} (linear
    // in p, so an end of the range is best); empty windows pass g on, all-occupied ones stop it.
    // Every block ray's p_t lies in the range (or its cell is empty: g_{t+1} <= the lo_t = 0 term,
    // or occupied: 0), so g bounds its gain, and it is at most the sum with the smallest p for the
    // visibility and the largest for the factor.
    if (mode != MODE_INFORMATION_GAIN) {
        floatv g = 0.0f;
        for (int t = marched_end - 1; t >= first_sample; --t) {
            const intv inside = (intv)(t) < end;
#if DP_SAMPLES  // what the march read at t (lanes inside marched it)
            const floatv c = window_lo[t];
            const floatv hi = window_hi[t];
#else
            const intv cell = inside ? origin + off[t] : origin;
            const floatv c = GATHER(code, cell);
            const floatv hi = WINDOW_HI(cell);
#endif
            const float weight = WEIGHT(t);
            const floatv at_lo = weight * ((1.0f - surface) + surface * c) + (1.0f - c) * g;
            const floatv at_hi = weight * ((1.0f - surface) + surface * hi) + (1.0f - hi) * g;
            g = (inside & (c >= 0.0f)) ? ((at_lo > at_hi) ? at_lo : at_hi) : ((inside & (c == -1.0f)) ? (floatv)(0.0f) : g);
        }
        hit = g;
    }
#endif
#if GAIN_ORIGINAL
    *gains = hit;
    *totals = total;
#else
#if GAIN_SENSOR
    if (mode != MODE_INFORMATION_GAIN) {
        hit = (1.0f - surface) * fmax(returned * weighted - early, (floatv)(0.0f)) + surface * landed;
    }
#endif
    *gains = hit * inv_total;
#endif
}

// G_r(v, h) for every (origin, ray): one work-item per ray and block of LANES origins (origins
// padded to a multiple of LANES); out is (n_origins / LANES, n_rays, LANES).
__kernel void ray_gain(__global const float *code, __global const int *origins, const int n_origins,
                       __global const int *offsets, const int n_rays, const int n_samples,
                       const int nu, const float inv_total, const float total_weight, const float eps,
                       const int mode, const float min_range, const float surface, const int own_rays,
                       __global float *out EXACT_KERNEL_PARAMS SENSOR_KERNEL_PARAMS SURFACE_KERNEL_PARAMS)
{
    const int gid = get_global_id(0);
    if (gid >= n_origins / LANES * n_rays) {
        return;
    }
    const int n = gid / n_rays;
    const int h = gid - n * n_rays;
    // own_rays: block n marches its own rays, rows n * n_rays .. n * n_rays + n_rays - 1 of the
    // offsets (each origin its own ray set, e.g. its camera's image); else every block row h
    const int ray = own_rays ? gid : h;
    floatv gains, totals;
    march_rays(code, origins + (size_t)n * LANES, offsets + (size_t)ray * n_samples, 0, n_samples, nu, inv_total,
               total_weight, eps, mode, min_range, surface, &gains, &totals EXACT_ARGS(ray) SENSOR_ARGS(ray)
               SURFACE_ARGS);
#if GAIN_ORIGINAL
    gains = (totals > 0.0f) ? gains / totals : (floatv)(0.0f);
#endif
    LANES_AT(__global floatv, out + (size_t)gid * LANES) = gains;
}

// G_W(v, W) for every origin and candidate view, without storing ray gains in global memory.
// One work-group per block of consecutive origins (origins padded to whole work-groups), LANES
// origins per work-item: the lanes march the same ray from neighbouring cells (coherent loops
// and memory reads), into local memory (ray_gains[ray][origin]); then each work-item sums, per
// view, the view's rays for its lanes (view_start/view_rays: the view -> rays membership as
// compressed rows, rays ascending) into local memory after the ray gains, and the group writes
// them to out, (n_origins, n_views).
// group_sets: per work-group a row of set_stride words (set_stride = 0: one row for every
// group): first the bit set of the views to sum (view_words words; view w is bit w & 31 of word
// w >> 5), then the bit set of the rays to march. Views outside the set get 0 and masked-out rays
// count 0: a view is exact when it is in the set and all its rays are marched, else its value
// is a lower bound of its gain (the coarse-to-fine search leaves out views and rays that cannot
// win). The tests are the same for every work-item of the group: loops stay in lock step.
// GAIN_ORIGINAL: the rays' totals follow their hits in local memory (ray_totals[ray][origin],
// before the view sums) and a view's gain is sum(hits) / sum(totals) over its rays.
__kernel void view_gain(__global const float *code, __global const int *origins, const int n_origins,
                        __global const int *offsets, const int n_rays, const int n_samples,
                        const int nu, const float inv_total, const float total_weight, const float eps,
                        const int mode, const float min_range, const float surface,
                        __global const int *view_start, __global const int *view_rays, const int n_views,
                        __global const int *group_first_sample, __global const uint *group_sets, const int set_stride,
                        const int view_words, __local float *ray_gains, __global float *out
                        EXACT_KERNEL_PARAMS SENSOR_KERNEL_PARAMS SURFACE_KERNEL_PARAMS)
{
    const int lid = get_local_id(0);
    const int size = get_local_size(0) * LANES;  // origins per work-group
    const int first = get_group_id(0) * size;
    const int first_sample = group_first_sample[get_group_id(0)];
    __global const uint *view_set = group_sets + (size_t)get_group_id(0) * set_stride;
    __global const uint *ray_set = view_set + view_words;
#if GAIN_ORIGINAL
    __local float *ray_totals = ray_gains + (size_t)n_rays * size;  // [ray][origin]
    __local float *view_sums = ray_totals + (size_t)n_rays * size;  // [view][origin]
#else
    __local float *view_sums = ray_gains + (size_t)n_rays * size;  // [view][origin]
#endif
    for (int h = 0; h < n_rays; ++h) {
        floatv gains = 0.0f;
        floatv totals = 0.0f;
        if (((ray_set[h >> 5] >> (h & 31)) & 1u) != 0u) {
            march_rays(code, origins + first + lid * LANES, offsets + (size_t)h * n_samples, first_sample, n_samples,
                       nu, inv_total, total_weight, eps, mode, min_range, surface, &gains, &totals EXACT_ARGS(h)
                       SENSOR_ARGS(h) SURFACE_ARGS);
        }
        LANES_AT(__local floatv, ray_gains + (size_t)h * size + lid * LANES) = gains;
#if GAIN_ORIGINAL
        LANES_AT(__local floatv, ray_totals + (size_t)h * size + lid * LANES) = totals;
#endif
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    // each work-item sums the views of its own lanes' origins (a vector of sums per view) ...
    for (int w = 0; w < n_views; ++w) {
        floatv sum = 0.0f;
#if GAIN_ORIGINAL
        floatv total = 0.0f;
#endif
        if (((view_set[w >> 5] >> (w & 31)) & 1u) != 0u) {
            for (int i = view_start[w]; i < view_start[w + 1]; ++i) {
                sum += LANES_AT(__local floatv, ray_gains + (size_t)view_rays[i] * size + lid * LANES);
#if GAIN_ORIGINAL
                total += LANES_AT(__local floatv, ray_totals + (size_t)view_rays[i] * size + lid * LANES);
#endif
            }
        }
#if GAIN_ORIGINAL
        sum = (total > 0.0f) ? sum / total : (floatv)(0.0f);
#endif
        LANES_AT(__local floatv, view_sums + (size_t)w * size + lid * LANES) = sum;
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    // ... then the group writes them out, origin-major
    const int count = min(size, n_origins - first);
    for (int k = lid; k < count * n_views; k += get_local_size(0)) {
        const int o = k / n_views;
        const int w = k - o * n_views;
        out[(size_t)(first + o) * n_views + w] = view_sums[(size_t)w * size + o];
    }
}
