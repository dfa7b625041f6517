/* CPU Gaussian compositor (forward + hand-written backward) for gsslam.mapping.rasterize_cpu.
 *
 * Built into a small shared library loaded with ctypes (no Python or torch headers), once with
 * REAL=float and once with REAL=double: at install time by setup.py, else at first use with the
 * system C compiler (gsslam/mapping/rasterize_build.py holds the one recipe both follow).
 *
 * Work is organised as exact per-pixel lists: pass 1 counts, per pixel, the (pixel, Gaussian) pairs
 * that pass the rules below; pass 2 fills the lists visiting Gaussians front to back, so each list
 * is already sorted by depth; the forward and backward passes then walk only those pairs.
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
        jobs[t].band0 = (int)((int64_t)base->H * t / threads);
        jobs[t].band1 = (int)((int64_t)base->H * (t + 1) / threads) - 1;
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
        jobs[t].band0 = (int)((int64_t)base->H * t / threads);
        jobs[t].band1 = (int)((int64_t)base->H * (t + 1) / threads) - 1;
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
