// Probabilistic ray-casting gain (SPEC §4) and view gain (SPEC §5, equation (7)).
//
// The grid is one float per cell ("code", see opencl.py: march_grid), C order [x][y][z] (2D
// grids have nz = 1), padded with one known-occupied cell on every side (2D: on x and y only):
//   code >= 0   unknown cell, occupancy probability p = code
//   code == -1  known occupied (p = 1), also the padding
//   code <= -2  known empty (p = 0), d = -1 - code >= 1 is the Chebyshev distance to the nearest
//               non-empty cell
// Sample t of ray h from origin v is the padded cell v + offsets[h][t], a linear index offset
// (precomputed from round(t * b_h)). Consecutive samples differ by at most one cell per axis
// (|b| <= 1), so samples t and t + k are at most k apart in the Chebyshev metric. Hence:
//   * a ray leaving the grid samples the occupied padding first and stops there, exactly as if
//     every cell outside the grid were known occupied: no bounds checks in the loop;
//   * samples 0 .. d - 1 of every ray from an origin at distance d are empty and change neither
//     H nor Pr (nor the information gain): view_gain starts the rays of a work-group at the
//     smallest d of its origins (first_sample). This is exact. (Jumping by d inside the loop is
//     exact too but breaks the lock-step loop pocl vectorizes across work-items: ~2x slower.)
//
// march_ray is the one implementation of the ray marching; ray_gain stores it per (origin,
// ray) (poses with their own frusta), view_gain sums it into the candidate views per origin.
#pragma OPENCL FP_CONTRACT OFF

#define MODE_PROBABILISTIC 0
#define MODE_INFORMATION_GAIN 1

inline float march_ray(__global const float *code, const int origin, __global const int *off,
                       const int first_sample, const int n_samples, const int nu, const float inv_total, const float eps,
                       const int mode, const float min_range)
{
    float visible = 1.0f;  // Pr(r_t) = prod_{i<t} (1 - p_i)
    float hit = 0.0f;      // H(v, h)
    for (int t = first_sample; t < n_samples; ++t) {
        const float c = code[origin + off[t]];
        if (c <= -2.0f) {
            continue;  // known empty
        }
        if (c < 0.0f) {
            break;  // known occupied (or outside the grid): Pr = 0 from here on
        }
        const float weight = (nu == 1) ? (float)t : (float)(t * t);
        if (mode == MODE_INFORMATION_GAIN) {
            if ((float)t >= min_range) {
                hit = weight;
            }
            break;
        }
        hit += visible * weight;
        visible *= 1.0f - c;
        if (visible <= eps) {
            break;
        }
    }
    return hit * inv_total;
}

// G_r(v, h) for every (origin, ray): one work-item each, out is (n_origins, n_rays).
__kernel void ray_gain(__global const float *code, __global const int *origins, const int n_origins,
                       __global const int *offsets, const int n_rays, const int n_samples,
                       const int nu, const float inv_total, const float eps,
                       const int mode, const float min_range,
                       __global float *out)
{
    const int gid = get_global_id(0);
    if (gid >= n_origins * n_rays) {
        return;
    }
    const int n = gid / n_rays;
    const int h = gid - n * n_rays;
    out[gid] = march_ray(code, origins[n], offsets + (size_t)h * n_samples, 0, n_samples, nu, inv_total,
                         eps, mode, min_range);
}

// G_W(v, W) for every origin and candidate view, without storing ray gains in global memory.
// One work-group per block of consecutive origins, one work-item per origin: neighbouring
// work-items march the same ray from neighbouring cells (coherent loops and memory reads), into
// local memory; then the group sums the rays of each (origin, view) pair (view_start/view_rays:
// the view -> rays membership as compressed rows, rays ascending). out is (n_origins, n_views).
// group_sets: per work-group a row of set_stride words (set_stride = 0: one row for every
// group): first the bit set of the views to sum (view_words words; view w is bit w & 31 of word
// w >> 5), then the bit set of the rays to march. Views outside the set get 0 and masked-out rays
// count 0: a view is exact when it is in the set and all its rays are marched, else its value
// is a lower bound of its gain (the coarse-to-fine search leaves out views and rays that cannot
// win). The tests are the same for every work-item of the group: loops stay in lock step.
__kernel void view_gain(__global const float *code, __global const int *origins, const int n_origins,
                        __global const int *offsets, const int n_rays, const int n_samples,
                        const int nu, const float inv_total, const float eps,
                        const int mode, const float min_range,
                        __global const int *view_start, __global const int *view_rays, const int n_views,
                        __global const int *group_first_sample, __global const uint *group_sets, const int set_stride,
                        const int view_words, __local float *ray_gains, __global float *out)
{
    const int lid = get_local_id(0);
    const int size = get_local_size(0);
    const int first = get_group_id(0) * size;
    const int first_sample = group_first_sample[get_group_id(0)];
    const int origin = origins[min(first + lid, n_origins - 1)];
    __local float *mine = ray_gains + (size_t)lid * n_rays;
    __global const uint *view_set = group_sets + (size_t)get_group_id(0) * set_stride;
    __global const uint *ray_set = view_set + view_words;
    for (int h = 0; h < n_rays; ++h) {
        if (((ray_set[h >> 5] >> (h & 31)) & 1u) == 0u) {
            mine[h] = 0.0f;
            continue;
        }
        mine[h] = march_ray(code, origin, offsets + (size_t)h * n_samples, first_sample, n_samples, nu,
                            inv_total, eps, mode, min_range);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    const int count = min(size, n_origins - first);
    for (int k = lid; k < count * n_views; k += size) {
        const int o = k / n_views;
        const int w = k - o * n_views;
        if (((view_set[w >> 5] >> (w & 31)) & 1u) == 0u) {
            out[(size_t)(first + o) * n_views + w] = 0.0f;
            continue;
        }
        __local const float *gains = ray_gains + (size_t)o * n_rays;
        float sum = 0.0f;
        for (int i = view_start[w]; i < view_start[w + 1]; ++i) {
            sum += gains[view_rays[i]];
        }
        out[(size_t)(first + o) * n_views + w] = sum;
    }
}
