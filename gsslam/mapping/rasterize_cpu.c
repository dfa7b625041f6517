/* CPU Gaussian compositor and EWA projection (forward + hand-written backward each) for
 * gsslam.mapping.rasterize_cpu.
 *
 * Built into a small shared library loaded with ctypes (no Python or torch headers), once with
 * REAL=float and once with REAL=double: at install time by setup.py, else at first use with the
 * system C compiler (gsslam/mapping/rasterize_build.py holds the one recipe both follow).
 *
 * Work is organised as exact per-pixel lists: pass 1 counts, per pixel, the (pixel, Gaussian) pairs
 * that pass the rules below; pass 2 fills the lists visiting Gaussians front to back, so each list
 * is already sorted by depth; the forward and backward passes then walk only those pairs. Optionally
 * (the default since session 8) pass 1 also records every row's span for pass 2 to read, and pass 2
 * records each pair's exp(-power) for the backward: the same arithmetic, bit for bit, done once.
 * The projection (end of the file) follows projection.project_gaussians.
 *
 * Rules (identical to rasterize_reference.py): pixel centres at integer coordinates; a pair exists
 * when 0.5 d^T conic d <= POWER_CUTOFF and o * exp(-power) >= 1/255; alpha = min(0.99, o exp(-power));
 * compositing stops before the first pair that would bring the transmittance below T_MIN.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <pthread.h>

#define MAX_THREADS 64

#ifndef REAL
#define REAL float
#endif
#define SUFFIX_(name, s) name##_##s
#define SUFFIX(name, s) SUFFIX_(name, s)
#ifndef TAG
#define TAG f32
#endif
#define FN(name) SUFFIX(name, TAG)
#ifndef EXP
#define EXP exp
#endif

/* The hash of this file and the flags it was built from, so that the loader can tell a library built
 * from an older copy of this file (an edited checkout) from a current one. */
#ifdef GSSLAM_SOURCE_KEY
const char *FN(gsslam_source_key)(void) { return GSSLAM_SOURCE_KEY; }
#endif

#define POWER_CUTOFF 4.5
#define ALPHA_MIN (1.0 / 255.0)
#define ALPHA_MAX 0.99
#define T_MIN 1e-4

typedef REAL real;

/* Pair predicate of pixel (x, y): o * exp(-power) when inside the ellipse and >= ALPHA_MIN, else -1;
 * *G = exp(-power) (the Gaussian's falloff, which the backward needs) when not -1. */
static inline real pair_alpha_raw(const real *mu, const real *con, real o, int x, int y, real *G) {
    real dx = (real)x - mu[0], dy = (real)y - mu[1];
    real pw = (real)0.5 * (con[0] * dx * dx + con[2] * dy * dy) + con[1] * dx * dy;
    if (pw > (real)POWER_CUTOFF) return -1;
    *G = (real)EXP(-pw);
    real a = o * *G;
    return a < (real)ALPHA_MIN ? -1 : a;
}

/* pair_alpha_raw(...) >= 0, evaluated without exp away from the opacity cut-off: ``lcut`` is
 * log(255 o), so o exp(-power) >= 1/255 <=> power <= lcut up to rounding, which only matters close by. */
static inline int pair_in(const real *mu, const real *con, real o, double lcut, int x, int y) {
    real dx = (real)x - mu[0], dy = (real)y - mu[1];
    real pw = (real)0.5 * (con[0] * dx * dx + con[2] * dy * dy) + con[1] * dx * dy;
    if (pw > (real)POWER_CUTOFF) return 0;
    if (pw < lcut - 1e-3) return 1;
    if (pw > lcut + 1e-3) return 0;
    return o * (real)EXP(-pw) >= (real)ALPHA_MIN;
}

/* Row span of Gaussian g: the integer x in [*lo, *hi] (clipped to the image) whose pair predicate
 * holds. Solves the quadratic for a first guess, then moves the ends with the exact predicate, so
 * the set is exactly the one pair_alpha_raw describes (it is an interval: power is convex in x). */
static inline void row_span(const real *mu, const real *con, real o, double cut, double lcut, int y, int W,
                            int *lo, int *hi) {
    double a = con[0], b = con[1], dy = (double)y - mu[1];
    double disc = 2.0 * a * cut - (a * con[2] - b * b) * dy * dy;
    double centre = mu[0] - b * dy / a;
    double half = disc > 0 ? sqrt(disc) / a : 0.0;
    int l = (int)ceil(centre - half), h = (int)floor(centre + half);
    if (l > h) { l = (int)floor(centre); h = l + 1; }
    if (l < 0) l = 0;
    if (h > W - 1) h = W - 1;
    while (l <= h && !pair_in(mu, con, o, lcut, l, y)) ++l;
    while (h >= l && !pair_in(mu, con, o, lcut, h, y)) --h;
    if (l <= h) {
        while (l > 0 && pair_in(mu, con, o, lcut, l - 1, y)) --l;
        while (h < W - 1 && pair_in(mu, con, o, lcut, h + 1, y)) ++h;
    }
    *lo = l; *hi = h;
}

/* Rows [*y0, *y1] of Gaussian g within [band0, band1], widened by one row for rounding; 0 if none. */
static inline int row_range(const real *mu, const real *con, real o, int64_t r, int band0, int band1,
                            double *cut, int *y0, int *y1) {
    if (r <= 0 || o < (real)ALPHA_MIN) return 0;
    double c = log(255.0 * (double)o) + 1e-3;
    if (c > POWER_CUTOFF + 1e-3) c = POWER_CUTOFF + 1e-3;
    double det = (double)con[0] * con[2] - (double)con[1] * con[1];
    if (!(det > 0) || !(con[0] > 0)) return 0;
    double ext = sqrt(2.0 * c * con[0] / det);
    int a = (int)floor(mu[1] - ext) - 1, b = (int)ceil(mu[1] + ext) + 1;
    if (a < band0) a = band0;
    if (b > band1) b = band1;
    if (a > b) return 0;
    *cut = c; *y0 = a; *y1 = b;
    return 1;
}

typedef struct {
    int64_t N; int W, H, band0, band1;
    const real *means2d, *conics, *opac;
    const int64_t *radii, *order, *offsets;
    int64_t *cursor;
    int32_t *counts, *pair_gid;
    real *pair_alpha;
    const int64_t *span_start; /* NULL, or each Gaussian's first row in `spans` (see span_rows) */
    int32_t *spans;            /* [rows, 2] (lo, hi) of every row: written by the count pass, read by fill */
    real *pair_G;              /* NULL, or exp(-power) of every pair (fill writes, the backward reads) */
} pair_job;

/* Index in `spans` of Gaussian g's row y (its rows over the whole image start at span_start[g]). */
static inline int64_t span_index(const pair_job *j, int64_t g, const real *mu, const real *con, real o, int y) {
    double cut; int y0 = y, y1;
    row_range(mu, con, o, j->radii[g], 0, j->H - 1, &cut, &y0, &y1);
    return j->span_start[g] + (y - y0);
}

/* Pass 1 on one band of rows: counts[p] = number of pairs of pixel p. */
static void *count_band(void *arg) {
    pair_job *j = (pair_job *)arg;
    for (int64_t g = 0; g < j->N; ++g) {
        const real *mu = j->means2d + 2 * g, *con = j->conics + 3 * g;
        real o = j->opac[g];
        double cut; int y0, y1;
        if (!row_range(mu, con, o, j->radii[g], j->band0, j->band1, &cut, &y0, &y1)) continue;
        double lcut = log(255.0 * (double)o);
        int32_t *span = j->spans ? j->spans + 2 * span_index(j, g, mu, con, o, y0) : NULL;
        for (int y = y0; y <= y1; ++y) {
            int lo, hi;
            row_span(mu, con, o, cut, lcut, y, j->W, &lo, &hi);
            int32_t *row = j->counts + (int64_t)y * j->W;
            for (int x = lo; x <= hi; ++x) row[x] += 1;
            if (span) { span[0] = lo; span[1] = hi; span += 2; }
        }
    }
    return NULL;
}

/* Pass 2 on one band: fill the lists visiting Gaussians in depth order (lists come out sorted). */
static void *fill_band(void *arg) {
    pair_job *j = (pair_job *)arg;
    for (int64_t k = 0; k < j->N; ++k) {
        int64_t g = j->order[k];
        const real *mu = j->means2d + 2 * g, *con = j->conics + 3 * g;
        real o = j->opac[g];
        double cut; int y0, y1;
        if (!row_range(mu, con, o, j->radii[g], j->band0, j->band1, &cut, &y0, &y1)) continue;
        double lcut = log(255.0 * (double)o);
        const int32_t *span = j->spans ? j->spans + 2 * span_index(j, g, mu, con, o, y0) : NULL;
        for (int y = y0; y <= y1; ++y) {
            int lo, hi;
            if (span) { lo = span[0]; hi = span[1]; span += 2; }
            else row_span(mu, con, o, cut, lcut, y, j->W, &lo, &hi);
            for (int x = lo; x <= hi; ++x) {
                real G = 0;
                real a = pair_alpha_raw(mu, con, o, x, y, &G);
                int64_t slot = j->cursor[(int64_t)y * j->W + x]++;
                j->pair_gid[slot] = (int32_t)g;
                j->pair_alpha[slot] = a < (real)ALPHA_MAX ? a : (real)ALPHA_MAX;
                if (j->pair_G) j->pair_G[slot] = G;
            }
        }
    }
    return NULL;
}

/* First row of band t of `threads`: equal rows without offsets (the count pass), else about equal pairs
 * (offsets[W * H + 1] from the counts), so that a band with the dense part of the view is not the one
 * every other thread waits for. A band may be empty. */
static int band_start(const int64_t *offsets, int W, int H, int t, int threads) {
    if (t >= threads) return H;
    if (!offsets) return (int)((int64_t)H * t / threads);
    int64_t goal = offsets[(int64_t)W * H] / threads * t;
    int lo = 0, hi = H; /* the first row whose pixels start at or after the goal */
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (offsets[(int64_t)mid * W] >= goal) hi = mid; else lo = mid + 1;
    }
    return lo;
}

/* Run fn on `threads` bands of rows (threads <= MAX_THREADS), the last one on the calling thread. */
static void run_bands(void *(*fn)(void *), pair_job *base, int threads) {
    pair_job jobs[MAX_THREADS];
    pthread_t tid[MAX_THREADS];
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    if (threads > base->H) threads = base->H;
    int started = 0;
    for (int t = 0; t < threads; ++t) {
        jobs[t] = *base;
        jobs[t].band0 = band_start(base->offsets, base->W, base->H, t, threads);
        jobs[t].band1 = band_start(base->offsets, base->W, base->H, t + 1, threads) - 1;
    }
    for (int t = 0; t < threads - 1; ++t)
        if (pthread_create(&tid[t], NULL, fn, &jobs[t]) == 0) started = t + 1; else break;
    for (int t = started; t < threads; ++t) fn(&jobs[t]);
    for (int t = 0; t < started; ++t) pthread_join(tid[t], NULL);
}

/* Rows of every Gaussian over the whole image: span_start[g] is the index of g's first row among the
 * rows of all Gaussians (span_start[N] = the total, returned), 0 rows for a Gaussian that draws none. */
int64_t FN(span_rows)(int64_t N, int W, int H, const real *means2d, const real *conics, const real *opac,
                      const int64_t *radii, int64_t *span_start) {
    (void)W;
    int64_t total = 0;
    for (int64_t g = 0; g < N; ++g) {
        double cut; int y0, y1;
        span_start[g] = total;
        if (row_range(means2d + 2 * g, conics + 3 * g, opac[g], radii[g], 0, H - 1, &cut, &y0, &y1))
            total += y1 - y0 + 1;
    }
    span_start[N] = total;
    return total;
}

/* Pass 1: counts[p] = number of pairs of pixel p. Returns the total. With span_start (from span_rows)
 * it also writes every row's (lo, hi) to spans [rows, 2], so that fill_pairs need not find them again;
 * both may be NULL. */
int64_t FN(count_pairs)(int64_t N, int W, int H, const real *means2d, const real *conics,
                        const real *opac, const int64_t *radii, int32_t *counts, const int64_t *span_start,
                        int32_t *spans, int threads) {
    memset(counts, 0, sizeof(int32_t) * (size_t)W * H);
    pair_job j = {N, W, H, 0, H - 1, means2d, conics, opac, radii, NULL, NULL, NULL, counts, NULL, NULL,
                  span_start, spans, NULL};
    run_bands(count_band, &j, threads);
    int64_t total = 0;
    for (int64_t p = 0; p < (int64_t)W * H; ++p) total += counts[p];
    return total;
}

/* Pass 2: fill the lists (offsets[P + 1] from the counts) visiting Gaussians in depth order. With
 * span_start / spans (as count_pairs wrote them) the rows' spans are read, not found again; with pair_G
 * every pair's exp(-power) is stored for the backward. Each may be NULL. */
void FN(fill_pairs)(int64_t N, int W, int H, const real *means2d, const real *conics, const real *opac,
                    const int64_t *radii, const int64_t *order, const int64_t *offsets, int64_t *cursor,
                    int32_t *pair_gid, real *pair_alpha, const int64_t *span_start, int32_t *spans,
                    real *pair_G, int threads) {
    memcpy(cursor, offsets, sizeof(int64_t) * (size_t)W * H);
    pair_job j = {N, W, H, 0, H - 1, means2d, conics, opac, radii, order, offsets, cursor, NULL, pair_gid,
                  pair_alpha, span_start, spans, pair_G};
    run_bands(fill_band, &j, threads);
}

typedef struct {
    int W, H, F, band0, band1;
    const int64_t *offsets;
    const int32_t *pair_gid;
    const real *pair_alpha, *pair_G, *means2d, *conics, *opac, *feat, *g_feat_out, *g_alpha_out;
    real *out_feat, *out_T;
    int32_t *n_used;
    const real *out_T_in;
    const int32_t *n_used_in;
    real *g_means2d, *g_conics, *g_opac, *g_feat; /* this band's own accumulators */
} comp_job;

static void *forward_band(void *arg) {
    comp_job *j = (comp_job *)arg;
    int F = j->F;
    for (int64_t p = (int64_t)j->band0 * j->W; p < (int64_t)(j->band1 + 1) * j->W; ++p) {
        real T = 1;
        real *acc = j->out_feat + p * F;
        for (int c = 0; c < F; ++c) acc[c] = 0;
        int64_t k = j->offsets[p], end = j->offsets[p + 1];
        for (; k < end; ++k) {
            real a = j->pair_alpha[k];
            real Tn = T * (1 - a);
            if (Tn < (real)T_MIN) break;
            const real *f = j->feat + (int64_t)j->pair_gid[k] * F;
            real w = a * T;
            for (int c = 0; c < F; ++c) acc[c] += w * f[c];
            T = Tn;
        }
        j->out_T[p] = T;
        j->n_used[p] = (int32_t)(k - j->offsets[p]);
    }
    return NULL;
}

static void *backward_band(void *arg) {
    comp_job *j = (comp_job *)arg;
    int F = j->F;
    real S[64];
    for (int y = j->band0; y <= j->band1; ++y)
        for (int x = 0; x < j->W; ++x) {
            int64_t p = (int64_t)y * j->W + x;
            int n = j->n_used_in[p];
            if (n == 0) continue;
            const real *go = j->g_feat_out + p * F;
            real gA = j->g_alpha_out[p];
            real T_final = j->out_T_in[p];
            real T = T_final;
            for (int c = 0; c < F; ++c) S[c] = 0;
            for (int64_t k = j->offsets[p] + n - 1; k >= j->offsets[p]; --k) {
                int64_t g = j->pair_gid[k];
                real a = j->pair_alpha[k];
                real one_minus = 1 - a;
                real Ti = T / one_minus;
                const real *f = j->feat + g * F;
                real *gf = j->g_feat + g * F;
                real w = a * Ti;
                real dL_da = gA * T_final / one_minus;
                for (int c = 0; c < F; ++c) {
                    gf[c] += w * go[c];
                    dL_da += Ti * go[c] * (f[c] - S[c]);
                    S[c] = a * f[c] + one_minus * S[c];
                }
                T = Ti;
                /* alpha = min(0.99, o G): no gradient through the clamp */
                const real *mu = j->means2d + 2 * g, *con = j->conics + 3 * g;
                real dx = (real)x - mu[0], dy = (real)y - mu[1];
                real G;
                if (j->pair_G) {
                    G = j->pair_G[k];
                } else {
                    real pw = (real)0.5 * (con[0] * dx * dx + con[2] * dy * dy) + con[1] * dx * dy;
                    G = (real)EXP(-pw);
                }
                real o = j->opac[g];
                if (o * G >= (real)ALPHA_MAX) continue;
                j->g_opac[g] += dL_da * G;
                real dL_dpw = -dL_da * o * G;
                j->g_means2d[2 * g] += -dL_dpw * (con[0] * dx + con[1] * dy);
                j->g_means2d[2 * g + 1] += -dL_dpw * (con[2] * dy + con[1] * dx);
                j->g_conics[3 * g] += dL_dpw * (real)0.5 * dx * dx;
                j->g_conics[3 * g + 1] += dL_dpw * dx * dy;
                j->g_conics[3 * g + 2] += dL_dpw * (real)0.5 * dy * dy;
            }
        }
    return NULL;
}

static void run_comp(void *(*fn)(void *), comp_job *jobs, int threads) {
    pthread_t tid[MAX_THREADS];
    int started = 0;
    for (int t = 0; t < threads - 1; ++t)
        if (pthread_create(&tid[t], NULL, fn, &jobs[t]) == 0) started = t + 1; else break;
    for (int t = started; t < threads; ++t) fn(&jobs[t]);
    for (int t = 0; t < started; ++t) pthread_join(tid[t], NULL);
}

static int split(comp_job *base, comp_job *jobs, int threads) {
    if (threads < 1) threads = 1;
    if (threads > MAX_THREADS) threads = MAX_THREADS;
    if (threads > base->H) threads = base->H;
    for (int t = 0; t < threads; ++t) {
        jobs[t] = *base;
        jobs[t].band0 = band_start(base->offsets, base->W, base->H, t, threads);
        jobs[t].band1 = band_start(base->offsets, base->W, base->H, t + 1, threads) - 1;
    }
    return threads;
}

/* Forward: out_feat[P, F] = sum w_i f_i, out_T[P] = final transmittance, n_used[P] pairs composited. */
void FN(composite_forward)(int W, int H, int F, const int64_t *offsets, const int32_t *pair_gid,
                           const real *pair_alpha, const real *feat, real *out_feat, real *out_T,
                           int32_t *n_used, int threads) {
    comp_job base = {0};
    comp_job jobs[MAX_THREADS];
    base.W = W; base.H = H; base.F = F; base.offsets = offsets; base.pair_gid = pair_gid;
    base.pair_alpha = pair_alpha; base.feat = feat; base.out_feat = out_feat; base.out_T = out_T;
    base.n_used = n_used;
    threads = split(&base, jobs, threads);
    run_comp(forward_band, jobs, threads);
}

/* Backward of composite_forward (with out_alpha = 1 - out_T) by reverse compositing, as in 3DGS.
 * Gradients are accumulated (+=) into the zero-initialised g_* arrays; bands other than the first
 * accumulate into private buffers that are summed at the end. pair_G (fill_pairs' exp(-power) of
 * every pair, or NULL: computed again) saves an exp per pair. Returns 0, or -1 when out of memory
 * or F > 64. */
int FN(composite_backward)(int W, int H, int F, int64_t N, const int64_t *offsets, const int32_t *pair_gid,
                           const real *pair_alpha, const real *pair_G, const real *means2d, const real *conics,
                           const real *opac, const real *feat, const real *out_T, const int32_t *n_used,
                           const real *g_feat_out, const real *g_alpha_out, real *g_means2d,
                           real *g_conics, real *g_opac, real *g_feat, int threads) {
    if (F > 64) return -1;
    comp_job base = {0};
    comp_job jobs[MAX_THREADS];
    base.W = W; base.H = H; base.F = F; base.offsets = offsets; base.pair_gid = pair_gid;
    base.pair_alpha = pair_alpha; base.pair_G = pair_G; base.means2d = means2d; base.conics = conics;
    base.opac = opac;
    base.feat = feat; base.out_T_in = out_T; base.n_used_in = n_used; base.g_feat_out = g_feat_out;
    base.g_alpha_out = g_alpha_out;
    base.g_means2d = g_means2d; base.g_conics = g_conics; base.g_opac = g_opac; base.g_feat = g_feat;
    threads = split(&base, jobs, threads);
    int64_t stride = 2 + 3 + 1 + F;
    real *scratch = NULL;
    if (threads > 1) {
        scratch = (real *)calloc((size_t)(threads - 1) * N * stride, sizeof(real));
        if (!scratch) return -1;
        for (int t = 1; t < threads; ++t) {
            real *b = scratch + (t - 1) * N * stride;
            jobs[t].g_means2d = b; jobs[t].g_conics = b + 2 * N; jobs[t].g_opac = b + 5 * N;
            jobs[t].g_feat = b + 6 * N;
        }
    }
    run_comp(backward_band, jobs, threads);
    for (int t = 1; t < threads; ++t) {
        const real *b = scratch + (t - 1) * N * stride;
        for (int64_t i = 0; i < 2 * N; ++i) g_means2d[i] += b[i];
        for (int64_t i = 0; i < 3 * N; ++i) g_conics[i] += b[2 * N + i];
        for (int64_t i = 0; i < N; ++i) g_opac[i] += b[5 * N + i];
        for (int64_t i = 0; i < F * N; ++i) g_feat[i] += b[6 * N + i];
    }
    free(scratch);
    return 0;
}

/* ---- EWA projection (forward + hand-written backward): the maths of projection.project_gaussians ----
 *
 * Per Gaussian: p = R_cw m + t_cw; u = fx x/z + cx, v = fy y/z + cy (z replaced by 1 behind `near`);
 * J W with x/z, y/z clamped 30 % of the half field of view beyond the image; A = J W R_g S (2 x 3);
 * cov2d = A A^T + low_pass I; conic = cov2d^-1 (det clamped at 1e-12); the normal is the camera-frame
 * shortest axis (first smallest scale), flipped to face the camera; radius ceil(3 sqrt(lambda_max)),
 * 0 when behind `near`, off the image by more than it, or not finite. T is [4, 4] row-major, K [3, 3]. */

typedef struct {
    real lxp, lxn, lyp, lyn;
} proj_limits;

static proj_limits proj_lims(const real *K, int W, int H) {
    real fx = K[0], fy = K[4], cx = K[2], cy = K[5];
    real tan_x = (real)0.5 * (real)W / fx, tan_y = (real)0.5 * (real)H / fy;
    proj_limits l;
    l.lxp = ((real)W - cx) / fx + (real)0.3 * tan_x;
    l.lxn = cx / fx + (real)0.3 * tan_x;
    l.lyp = ((real)H - cy) / fy + (real)0.3 * tan_y;
    l.lyn = cy / fy + (real)0.3 * tan_y;
    return l;
}

/* Everything of one Gaussian's projection that the backward needs again. */
typedef struct {
    real p[3], z_safe, inv_z, cx_, cy_; /* cx_, cy_: the clamped x/z, y/z */
    int in_front, clip_x, clip_y;      /* clip_*: the clamp is active (no gradient through x/z) */
    real qn[4], qnorm, Rg[9], jw0[3], jw1[3], B0[3], B1[3], A0[3], A1[3];
    real a, b, c, det_raw, det;
    int axis;
    real n_world[3], facing;
} proj_one;

static void proj_compute(const real *m, const real *q, const real *s, const real *T, const real *K,
                         proj_limits l, real near, real low_pass, proj_one *o) {
    real fx = K[0], fy = K[4];
    for (int i = 0; i < 3; ++i) o->p[i] = T[4 * i] * m[0] + T[4 * i + 1] * m[1] + T[4 * i + 2] * m[2] + T[4 * i + 3];
    real x = o->p[0], y = o->p[1], z = o->p[2];
    o->in_front = z > near;
    o->z_safe = o->in_front ? z : (real)1;
    o->inv_z = (real)1 / o->z_safe;
    real xz = x * o->inv_z, yz = y * o->inv_z;
    o->clip_x = !(xz > -l.lxn && xz < l.lxp);
    o->clip_y = !(yz > -l.lyn && yz < l.lyp);
    o->cx_ = xz < -l.lxn ? -l.lxn : (xz > l.lxp ? l.lxp : xz);
    o->cy_ = yz < -l.lyn ? -l.lyn : (yz > l.lyp ? l.lyp : yz);
    real tx = o->z_safe * o->cx_, ty = o->z_safe * o->cy_;
    real iz2 = o->inv_z * o->inv_z;
    for (int j = 0; j < 3; ++j) {
        o->jw0[j] = fx * o->inv_z * T[j] - fx * tx * iz2 * T[8 + j];
        o->jw1[j] = fy * o->inv_z * T[4 + j] - fy * ty * iz2 * T[8 + j];
    }
    real nq = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    o->qnorm = nq > (real)1e-12 ? nq : (real)1e-12;
    for (int i = 0; i < 4; ++i) o->qn[i] = q[i] / o->qnorm;
    real w = o->qn[0], qx = o->qn[1], qy = o->qn[2], qz = o->qn[3];
    real *R = o->Rg;
    R[0] = 1 - 2 * (qy * qy + qz * qz); R[1] = 2 * (qx * qy - w * qz); R[2] = 2 * (qx * qz + w * qy);
    R[3] = 2 * (qx * qy + w * qz); R[4] = 1 - 2 * (qx * qx + qz * qz); R[5] = 2 * (qy * qz - w * qx);
    R[6] = 2 * (qx * qz - w * qy); R[7] = 2 * (qy * qz + w * qx); R[8] = 1 - 2 * (qx * qx + qy * qy);
    for (int k = 0; k < 3; ++k) {
        o->B0[k] = o->jw0[0] * R[k] + o->jw0[1] * R[3 + k] + o->jw0[2] * R[6 + k];
        o->B1[k] = o->jw1[0] * R[k] + o->jw1[1] * R[3 + k] + o->jw1[2] * R[6 + k];
        o->A0[k] = o->B0[k] * s[k];
        o->A1[k] = o->B1[k] * s[k];
    }
    o->a = o->A0[0] * o->A0[0] + o->A0[1] * o->A0[1] + o->A0[2] * o->A0[2] + low_pass;
    o->b = o->A0[0] * o->A1[0] + o->A0[1] * o->A1[1] + o->A0[2] * o->A1[2];
    o->c = o->A1[0] * o->A1[0] + o->A1[1] * o->A1[1] + o->A1[2] * o->A1[2] + low_pass;
    o->det_raw = o->a * o->c - o->b * o->b;
    o->det = o->det_raw > (real)1e-12 ? o->det_raw : (real)1e-12;
    o->axis = (s[0] <= s[1] && s[0] <= s[2]) ? 0 : (s[1] <= s[2] ? 1 : 2);
    for (int j = 0; j < 3; ++j) o->n_world[j] = R[3 * j + o->axis];
    real dot = 0;
    for (int i = 0; i < 3; ++i)
        dot += (T[4 * i] * o->n_world[0] + T[4 * i + 1] * o->n_world[1] + T[4 * i + 2] * o->n_world[2]) * o->p[i];
    o->facing = dot > 0 ? (real)-1 : (real)1;
}

void FN(project_forward)(int64_t N, const real *means, const real *quats, const real *scales, const real *T,
                         const real *K, int W, int H, double near, double low_pass, real *means2d,
                         real *cov2d, real *conics, real *depths, int64_t *radii, real *normals) {
    proj_limits l = proj_lims(K, W, H);
    for (int64_t g = 0; g < N; ++g) {
        proj_one o;
        proj_compute(means + 3 * g, quats + 4 * g, scales + 3 * g, T, K, l, (real)near, (real)low_pass, &o);
        real u = K[0] * o.p[0] * o.inv_z + K[2], v = K[4] * o.p[1] * o.inv_z + K[5];
        means2d[2 * g] = u; means2d[2 * g + 1] = v;
        cov2d[4 * g] = o.a; cov2d[4 * g + 1] = o.b; cov2d[4 * g + 2] = o.b; cov2d[4 * g + 3] = o.c;
        conics[3 * g] = o.c / o.det; conics[3 * g + 1] = -o.b / o.det; conics[3 * g + 2] = o.a / o.det;
        depths[g] = o.p[2];
        for (int i = 0; i < 3; ++i)
            normals[3 * g + i] = (T[4 * i] * o.n_world[0] + T[4 * i + 1] * o.n_world[1] + T[4 * i + 2] * o.n_world[2]) * o.facing;
        real mid = (real)0.5 * (o.a + o.c);
        real disc = mid * mid - (o.a * o.c - o.b * o.b);
        real lam = mid + sqrt(disc > 0 ? disc : 0);
        int64_t r = (int64_t)ceil((real)3.0 * sqrt(lam));
        int vis = o.in_front && isfinite(u) && isfinite(v) && (u + r >= 0) && (u - r <= W - 1) &&
                  (v + r >= 0) && (v - r <= H - 1);
        radii[g] = vis ? r : 0;
    }
}

/* Backward of project_forward: gradients of the means, quaternions, scales (written) and of T
 * (accumulated into g_T [16]) from those of means2d [N, 2], cov2d [N, 4], conics [N, 3], depths [N]
 * and normals [N, 3]. */
void FN(project_backward)(int64_t N, const real *means, const real *quats, const real *scales, const real *T,
                          const real *K, int W, int H, double near, double low_pass, const real *g_means2d,
                          const real *g_cov2d, const real *g_conics, const real *g_depths,
                          const real *g_normals, real *g_means, real *g_quats, real *g_scales, real *g_T) {
    proj_limits l = proj_lims(K, W, H);
    real fx = K[0], fy = K[4];
    double gR[9] = {0}, gt[3] = {0};
    for (int64_t g = 0; g < N; ++g) {
        proj_one o;
        const real *m = means + 3 * g, *s = scales + 3 * g;
        proj_compute(m, quats + 4 * g, s, T, K, l, (real)near, (real)low_pass, &o);
        /* conic = (c, -b, a) / det, cov2d = (a, b, b, c) */
        const real *gC = g_conics + 3 * g, *gV = g_cov2d + 4 * g;
        real ga = gC[2] / o.det + gV[0], gb = -gC[1] / o.det + gV[1] + gV[2], gc = gC[0] / o.det + gV[3];
        if (o.det_raw >= (real)1e-12) {
            real gdet = -(gC[0] * o.c - gC[1] * o.b + gC[2] * o.a) / (o.det * o.det);
            ga += gdet * o.c; gc += gdet * o.a; gb += gdet * (-2 * o.b);
        }
        real gjw0[3] = {0, 0, 0}, gjw1[3] = {0, 0, 0}, gRg[9];
        for (int k = 0; k < 3; ++k) {
            real gA0 = 2 * ga * o.A0[k] + gb * o.A1[k], gA1 = 2 * gc * o.A1[k] + gb * o.A0[k];
            g_scales[3 * g + k] = gA0 * o.B0[k] + gA1 * o.B1[k];
            real gB0 = gA0 * s[k], gB1 = gA1 * s[k];
            for (int j = 0; j < 3; ++j) {
                gjw0[j] += gB0 * o.Rg[3 * j + k];
                gjw1[j] += gB1 * o.Rg[3 * j + k];
                gRg[3 * j + k] = o.jw0[j] * gB0 + o.jw1[j] * gB1;
            }
        }
        /* normal = facing R_cw n_world */
        const real *gn = g_normals + 3 * g;
        for (int j = 0; j < 3; ++j) {
            real gnw = 0;
            for (int i = 0; i < 3; ++i) {
                gR[3 * i + j] += o.facing * gn[i] * o.n_world[j];
                gnw += T[4 * i + j] * o.facing * gn[i];
            }
            gRg[3 * j + o.axis] += gnw;
        }
        /* R_g from the normalized quaternion */
        real w = o.qn[0], x = o.qn[1], y = o.qn[2], z = o.qn[3];
        const real *G = gRg;
        real gq[4];
        gq[0] = 2 * (-z * G[1] + y * G[2] + z * G[3] - x * G[5] - y * G[6] + x * G[7]);
        gq[1] = 2 * (y * G[1] + z * G[2] + y * G[3] - 2 * x * G[4] - w * G[5] + z * G[6] + w * G[7] - 2 * x * G[8]);
        gq[2] = 2 * (-2 * y * G[0] + x * G[1] + w * G[2] + x * G[3] + z * G[5] - w * G[6] + z * G[7] - 2 * y * G[8]);
        gq[3] = 2 * (-2 * z * G[0] - w * G[1] + x * G[2] + w * G[3] - 2 * z * G[4] + y * G[5] + x * G[6] + y * G[7]);
        real qdot = o.qn[0] * gq[0] + o.qn[1] * gq[1] + o.qn[2] * gq[2] + o.qn[3] * gq[3];
        int normed = o.qnorm > (real)1e-12;
        for (int i = 0; i < 4; ++i) g_quats[4 * g + i] = (gq[i] - (normed ? o.qn[i] * qdot : 0)) / o.qnorm;
        /* jw0 = fx/z R0 - fx tx/z^2 R2, jw1 = fy/z R1 - fy ty/z^2 R2 (rows of R_cw) */
        real tx = o.z_safe * o.cx_, ty = o.z_safe * o.cy_, iz = o.inv_z, iz2 = iz * iz;
        real r0g = 0, r1g = 0, r2g0 = 0, r2g1 = 0;
        for (int j = 0; j < 3; ++j) {
            gR[j] += fx * iz * gjw0[j];
            gR[3 + j] += fy * iz * gjw1[j];
            gR[6 + j] += -fx * tx * iz2 * gjw0[j] - fy * ty * iz2 * gjw1[j];
            r0g += T[j] * gjw0[j]; r1g += T[4 + j] * gjw1[j];
            r2g0 += T[8 + j] * gjw0[j]; r2g1 += T[8 + j] * gjw1[j];
        }
        real g_iz = fx * r0g - 2 * fx * tx * iz * r2g0 + fy * r1g - 2 * fy * ty * iz * r2g1;
        real g_tx = -fx * iz2 * r2g0, g_ty = -fy * iz2 * r2g1;
        real g_zs = g_tx * o.cx_ + g_ty * o.cy_;
        real gp[3] = {0, 0, 0};
        if (!o.clip_x) { real gxz = g_tx * o.z_safe; gp[0] += gxz * iz; g_iz += gxz * o.p[0]; }
        if (!o.clip_y) { real gyz = g_ty * o.z_safe; gp[1] += gyz * iz; g_iz += gyz * o.p[1]; }
        /* means2d */
        const real *gm2 = g_means2d + 2 * g;
        gp[0] += gm2[0] * fx * iz; g_iz += gm2[0] * fx * o.p[0];
        gp[1] += gm2[1] * fy * iz; g_iz += gm2[1] * fy * o.p[1];
        g_zs += -g_iz * iz2;
        if (o.in_front) gp[2] += g_zs;
        gp[2] += g_depths[g];
        /* p = R_cw m + t */
        for (int j = 0; j < 3; ++j) g_means[3 * g + j] = T[j] * gp[0] + T[4 + j] * gp[1] + T[8 + j] * gp[2];
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) gR[3 * i + j] += gp[i] * m[j];
            gt[i] += gp[i];
        }
    }
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) g_T[4 * i + j] += (real)gR[3 * i + j];
        g_T[4 * i + 3] += (real)gt[i];
    }
}
