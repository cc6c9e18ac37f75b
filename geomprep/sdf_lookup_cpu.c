/* The SDF lookup's CPU kernel, built and called by geomprep/sdf_lookup_cpu.py.
 *
 * SDFLookup.query (geomprep/sdf_lookup.py: conventions, out-of-grid rule, brick layout) as one
 * pass over the points.  The query is bound by its 8 corner reads into a GB-sized brick stack;
 * in torch ops the index arithmetic around them takes ~25 passes over the points as well.  Here
 * each point's index is computed once, its corners' cache lines are prefetched at once, and the
 * reads happen a block of points later, so that many of them are in flight together.
 */
#include <math.h>
#include <stdint.h>

/* sdf_lookup.py's brick layout: a brick of 4^3 cells stores the 5^3 voxel centres at its cells'
 * corners, centre (i, j, k) at i * 25 + j * 5 + k, padded to 128 values. */
enum { BRICK_CELLS = 4, BRICK_VALUES = 128, STRIDE_I = 25, STRIDE_J = 5 };
/* Steps within a brick to a cell's 8 corners, dk slowest and di fastest (the lerps' order). */
static const int CORNER_STEPS[8] = {0, 25, 5, 30, 1, 26, 6, 31};

/* Points whose corners are read together (their index and weights stay in L1 meanwhile), and
 * envs per parallel task. */
enum { BLOCK = 128, ENVS_PER_TASK = 64 };

typedef struct {
    int count;
    int64_t index[BLOCK]; /* the cell's lower corner in the brick stack, in values */
    float t[3][BLOCK];    /* fraction across the cell along x, y, z */
    unsigned char nan[BLOCK];
} Block;

/* Reads the block's corners and writes its count values, trilinear, to out. */
static void interpolate(const void *bricks, int half, const Block *b, float *out) {
    float c[8][BLOCK];
    if (half) {
        const _Float16 *v = bricks;
        for (int i = 0; i < b->count; ++i)
            for (int j = 0; j < 8; ++j) c[j][i] = (float)v[b->index[i] + CORNER_STEPS[j]];
    } else {
        const float *v = bricks;
        for (int i = 0; i < b->count; ++i)
            for (int j = 0; j < 8; ++j) c[j][i] = v[b->index[i] + CORNER_STEPS[j]];
    }
    for (int i = 0; i < b->count; ++i) {
        float tx = b->t[0][i], ty = b->t[1][i], tz = b->t[2][i];
        float c00 = c[0][i] + tz * (c[4][i] - c[0][i]); /* (dj, di) = (0, 0) */
        float c01 = c[1][i] + tz * (c[5][i] - c[1][i]); /* (0, 1) */
        float c10 = c[2][i] + tz * (c[6][i] - c[2][i]); /* (1, 0) */
        float c11 = c[3][i] + tz * (c[7][i] - c[3][i]); /* (1, 1) */
        float c0 = c00 + ty * (c10 - c00), c1 = c01 + ty * (c11 - c01);
        out[i] = b->nan[i] ? NAN : c0 + tx * (c1 - c0);
    }
}

/* Signed distances out (E, K) float32 of world points (E, K, 3) to each env's object.
 *
 * bricks: (N, B, B, B, 128) float16 (half = 1) or float32 values; resolution R of the grids;
 * object_pos (E, 3), object_quat (E, 4) (w, x, y, z), object_ids (E,) int64; inv_voxel (N,),
 * shift (N, 3): u = R^T (p - pos) * inv_voxel + shift puts voxel i's centre at u = i.  All
 * float32, contiguous.  Returns the number of envs whose object id is not in 0..N-1 (their
 * distances are NaN); a point with a NaN coordinate gets NaN.
 */
int64_t sdf_query(const void *bricks, int half, int64_t n_objects, int64_t bricks_per_axis,
                  int64_t resolution, const float *points, const float *object_pos,
                  const float *object_quat, const int64_t *object_ids, const float *inv_voxel,
                  const float *shift, int64_t n_env, int64_t k, float *out, int n_threads) {
    const int64_t nb = bricks_per_axis, n_tasks = (n_env + ENVS_PER_TASK - 1) / ENVS_PER_TASK;
    const float upper = (float)resolution - 0.5f, top = (float)(resolution - 1);
    const float last_cell = (float)(resolution - 2);
    const char *base = bricks;
    const int64_t value_bytes = half ? 2 : 4;
    int64_t bad_ids = 0;
#pragma omp parallel for schedule(static) num_threads(n_threads) reduction(+ : bad_ids)
    for (int64_t task = 0; task < n_tasks; ++task) {
        const int64_t e_end = (task + 1) * ENVS_PER_TASK < n_env ? (task + 1) * ENVS_PER_TASK : n_env;
        Block b;
        b.count = 0;
        int64_t first = task * ENVS_PER_TASK * k; /* the output index of the block's first point */
        for (int64_t e = task * ENVS_PER_TASK; e < e_end; ++e) {
            const int64_t id = object_ids[e];
            if (id < 0 || id >= n_objects) {
                ++bad_ids;
                if (b.count) interpolate(bricks, half, &b, out + first);
                for (int64_t j = 0; j < k; ++j) out[e * k + j] = NAN;
                b.count = 0;
                first = (e + 1) * k;
                continue;
            }
            /* A = R^T / voxel, row by row (R from the quaternion, normalised by 2 / |q|^2). */
            const float *q = object_quat + 4 * e;
            const float w = q[0], x = q[1], y = q[2], z = q[3];
            const float s = 2.0f / (w * w + x * x + y * y + z * z), iv = inv_voxel[id];
            const float a[3][3] = {
                {(1 - s * (y * y + z * z)) * iv, s * (x * y + w * z) * iv, s * (x * z - w * y) * iv},
                {s * (x * y - w * z) * iv, (1 - s * (x * x + z * z)) * iv, s * (y * z + w * x) * iv},
                {s * (x * z + w * y) * iv, s * (y * z - w * x) * iv, (1 - s * (x * x + y * y)) * iv},
            };
            const float *o = object_pos + 3 * e, *sh = shift + 3 * id;
            for (int64_t j = 0; j < k; ++j) {
                const float *p = points + 3 * (e * k + j);
                const float d[3] = {p[0] - o[0], p[1] - o[1], p[2] - o[2]};
                float u[3];
                int outside = 0, nan = 0;
                for (int c = 0; c < 3; ++c) {
                    u[c] = sh[c] + a[c][0] * d[0] + a[c][1] * d[1] + a[c][2] * d[2];
                    nan |= isnan(u[c]);
                    outside |= (u[c] < -0.5f) | (u[c] > upper);
                }
                /* Clamp to the outer centres, keep the cell inside the grid; outside the cube
                 * snap to the closest voxel (round half to even, as torch.round).  fmaxf maps
                 * NaN to 0, so a NaN point still reads inside the stack. */
                int64_t cell[3];
                for (int c = 0; c < 3; ++c) {
                    const float v = fminf(fmaxf(u[c], 0.0f), top);
                    const float lower = fminf(floorf(v), last_cell);
                    b.t[c][b.count] = outside ? rintf(v - lower) : v - lower;
                    cell[c] = (int64_t)lower;
                }
                const int64_t brick = ((id * nb + cell[0] / BRICK_CELLS) * nb + cell[1] / BRICK_CELLS) * nb
                                      + cell[2] / BRICK_CELLS;
                const int64_t index = brick * BRICK_VALUES + (cell[0] % BRICK_CELLS) * STRIDE_I
                                      + (cell[1] % BRICK_CELLS) * STRIDE_J + cell[2] % BRICK_CELLS;
                /* The corners are values 0-6 and 25-31 from index: at most 2 cache lines in
                 * float16 (those of the first and last value), 4 in float32. */
                __builtin_prefetch(base + index * value_bytes);
                __builtin_prefetch(base + (index + 31) * value_bytes);
                if (!half) {
                    __builtin_prefetch(base + (index + 6) * value_bytes);
                    __builtin_prefetch(base + (index + 25) * value_bytes);
                }
                b.index[b.count] = index;
                b.nan[b.count] = (unsigned char)nan;
                if (++b.count == BLOCK) {
                    interpolate(bricks, half, &b, out + first);
                    first += BLOCK;
                    b.count = 0;
                }
            }
        }
        if (b.count) interpolate(bricks, half, &b, out + first);
    }
    return bad_ids;
}
