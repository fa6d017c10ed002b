/*
 * sample.c: reads a terrabake asset through the C ABI (capi/include/terrabake.h)
 * and prints what it read, one fact per line, floats as their IEEE bits, so
 * that `diff` against `cargo run -p terrabake-capi --example reference`
 * (the same facts from the Rust reader) proves the two equal.
 *
 *   make capi && target/capi/sample ASSET
 *
 * It also traces the same rays from four threads at once, and checks that
 * bad calls fail with a status and a message instead of crashing.
 * Exit status: 0 on success, 1 on any failure (the message is printed).
 */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "terrabake.h"

static uint32_t f32_bits(float v) {
    uint32_t b;
    memcpy(&b, &v, sizeof b);
    return b;
}

static unsigned long long f64_bits(double v) {
    unsigned long long b;
    memcpy(&b, &v, sizeof b);
    return b;
}

/* Stops the program where a call that must succeed fails. */
static void check(tb_status s, const char *what) {
    if (s != TB_OK) {
        fprintf(stderr, "sample: %s: %s: %s\n", what, tb_status_name(s), tb_last_error());
        exit(1);
    }
}

/* The rays every tracer is asked: from 50 m above the highest post over
 * the DEM's middle, down and outwards in eight directions, and one that
 * looks up and leaves. */
#define RAYS 9
static void rays(const tb_asset *asset, tb_ray out[RAYS]) {
    tb_grid g;
    check(tb_grid_info(asset, &g), "grid");
    size_t h;
    check(tb_find_layer(asset, "height", 0, &h), "find height");
    /* Above the highest post. */
    size_t n = (size_t)g.width * g.height;
    float *z = malloc(sizeof(float) * n);
    tb_window all = {0, 0, g.width, g.height};
    check(tb_read_window(asset, h, 0, all, z, n), "read heights");
    float top = -INFINITY;
    for (size_t i = 0; i < n; i++) {
        if (z[i] > top) top = z[i];
    }
    free(z);
    /* Exact decimal directions, so that the reference needs no libm. */
    static const double dirs[RAYS][2] = {{1, 0},     {0.7, 0.7},   {0, 1},    {-0.7, 0.7}, {-1, 0},
                                         {-0.7, -0.7}, {0, -1},    {0.7, -0.7}, {0.3, 0.2}};
    for (int k = 0; k < RAYS; k++) {
        tb_ray r = {{0.5 * (g.width - 1) * g.dx, 0.5 * (g.height - 1) * g.dy, top + 50.0},
                    {dirs[k][0], dirs[k][1], k == RAYS - 1 ? 0.5 : -0.05 - 0.02 * k},
                    0.0,
                    INFINITY};
        out[k] = r;
    }
}

struct job {
    const tb_asset *asset;
    const tb_ray *rays;
    tb_hit hits[RAYS];
    tb_status status;
};

static void *trace_all(void *arg) {
    struct job *j = arg;
    j->status = TB_OK;
    for (int k = 0; k < RAYS && j->status == TB_OK; k++) {
        j->status = tb_trace(j->asset, &j->rays[k], TB_INCREMENTAL, &j->hits[k]);
    }
    return NULL;
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: sample ASSET\n");
        return 2;
    }
    printf("format %u\n", tb_format_version());

    /* A missing asset fails with a status and a message naming it. */
    tb_asset *missing = (tb_asset *)1;
    tb_status s = tb_open("/nonexistent/terrabake/asset", &missing);
    if (s == TB_OK || missing != NULL || strstr(tb_last_error(), "/nonexistent") == NULL) {
        fprintf(stderr, "sample: opening a missing asset: %s, %s\n", tb_status_name(s), tb_last_error());
        return 1;
    }
    if (tb_layer_count(NULL, NULL) != TB_NULL_ARGUMENT) {
        fprintf(stderr, "sample: NULL asset not refused\n");
        return 1;
    }

    tb_asset *asset = NULL;
    s = tb_open(argv[1], &asset);
    if (s != TB_OK) {
        /* A damaged asset: the message is the point (valgrind runs this). */
        printf("open failed %s: %s\n", tb_status_name(s), tb_last_error());
        return 0;
    }

    size_t count;
    check(tb_layer_count(asset, &count), "layer count");
    printf("layers %zu\n", count);
    for (size_t i = 0; i < count; i++) {
        tb_layer l;
        check(tb_layer_info(asset, i, &l), "layer info");
        printf("layer %s@%u elem %u bytes %u bands %u size %ux%u tile %u tiles %ux%u azimuths",
               l.name, l.level, l.elem, l.elem_bytes, l.bands, l.width, l.height, l.tile_size,
               l.tiles_x, l.tiles_y);
        for (size_t b = 0; b < l.band_azimuth_count; b++) printf(" %016llx", f64_bits(l.band_azimuths[b]));
        printf("\n");

        /* A window of band 0 (and of the last band) near the middle, decoded. */
        uint32_t ww = l.width < 5 ? l.width : 5, wh = l.height < 4 ? l.height : 4;
        tb_window win = {l.width / 3, l.height / 2, ww, wh};
        if (win.x0 + ww > l.width) win.x0 = l.width - ww;
        if (win.y0 + wh > l.height) win.y0 = l.height - wh;
        float vals[20];
        uint32_t bands[2] = {0, l.bands - 1};
        for (int b = 0; b < 2; b++) {
            check(tb_read_window(asset, i, bands[b], win, vals, (size_t)ww * wh), "read window");
            printf("window %s@%u band %u at %u,%u:", l.name, l.level, bands[b], win.x0, win.y0);
            for (uint32_t k = 0; k < ww * wh; k++) printf(" %08x", f32_bits(vals[k]));
            printf("\n");
        }

        /* The first raw tile, borrowed: its length and a checksum of its bytes. */
        const void *data = NULL;
        size_t bytes = 0;
        s = tb_tile(asset, i, 0, 0, 0, &data, &bytes);
        if (s == TB_OK) {
            unsigned long long sum = 0xcbf29ce484222325ULL; /* FNV-1a */
            for (size_t k = 0; k < bytes; k++) {
                sum = (sum ^ ((const unsigned char *)data)[k]) * 0x100000001b3ULL;
            }
            printf("tile %s@%u 0,0 bytes %zu fnv %016llx\n", l.name, l.level, bytes, sum);
        } else if (s == TB_WRONG_TYPE) {
            printf("tile %s@%u 0,0 compressed\n", l.name, l.level);
        } else {
            check(s, "tile");
        }
        /* Out of range is a status, not a crash. */
        if (tb_tile(asset, i, l.bands, 0, 0, &data, &bytes) != TB_OUT_OF_RANGE) {
            fprintf(stderr, "sample: band %u of %s not refused\n", l.bands, l.name);
            return 1;
        }
    }

    size_t nope;
    if (tb_find_layer(asset, "no_such_layer", 0, &nope) != TB_NO_LAYER) {
        fprintf(stderr, "sample: a missing layer was found\n");
        return 1;
    }

    /* Heights: bilinear at grid points between posts, and outside. */
    size_t h;
    tb_layer hi;
    check(tb_find_layer(asset, "height", 0, &h), "find height");
    check(tb_layer_info(asset, h, &hi), "height info");
    for (int k = 0; k < 7; k++) {
        double gx = (hi.width - 1) * (0.1 + 0.13 * k), gy = (hi.height - 1) * (0.85 - 0.11 * k);
        if (k == 6) gx = -1.0;
        float z;
        check(tb_height_bilinear(asset, gx, gy, &z), "bilinear");
        printf("bilinear %016llx %016llx %08x\n", f64_bits(gx), f64_bits(gy), f32_bits(z));
    }

    /* Rays, by every method the asset can serve. */
    tb_ray r[RAYS];
    rays(asset, r);
    for (uint32_t m = TB_INCREMENTAL; m <= TB_BRUTE_FORCE; m++) {
        for (int k = 0; k < RAYS; k++) {
            tb_hit hit;
            s = tb_trace(asset, &r[k], m, &hit);
            if (s == TB_NO_LAYER) {
                printf("trace method %u unavailable\n", m);
                break;
            }
            check(s, "trace");
            printf("trace method %u ray %d hit %u cell %u,%u t %016llx\n", m, k, hit.hit, hit.cell[0],
                   hit.cell[1], f64_bits(hit.hit ? hit.t : 0.0));
        }
    }
    if (tb_trace(asset, &r[0], 99, &(tb_hit){0}) != TB_INVALID_ARGUMENT) {
        fprintf(stderr, "sample: method 99 not refused\n");
        return 1;
    }

    /* Four threads trace the same rays at once: the same hits. */
    struct job jobs[4];
    pthread_t threads[4];
    for (int t = 0; t < 4; t++) {
        jobs[t].asset = asset;
        jobs[t].rays = r;
        pthread_create(&threads[t], NULL, trace_all, &jobs[t]);
    }
    for (int t = 0; t < 4; t++) pthread_join(threads[t], NULL);
    for (int t = 0; t < 4; t++) {
        check(jobs[t].status, "threaded trace");
        for (int k = 0; k < RAYS; k++) {
            if (jobs[t].hits[k].hit != jobs[0].hits[k].hit || jobs[t].hits[k].t != jobs[0].hits[k].t) {
                fprintf(stderr, "sample: thread %d ray %d differs\n", t, k);
                return 1;
            }
        }
    }
    printf("threads 4 agree\n");

    /* The sun from stored horizons, where the asset has them: low suns
     * from four sides at posts along a diagonal. */
    tb_sun suns[4] = {{90.0, 2.0, 0.27}, {200.0, 4.0, 0.27}, {300.0, 1.0, 0.27}, {45.0, 8.0, 0.27}};
    int lit = 1;
    for (int p = 0; p < 6 && lit; p++) {
        uint32_t x = hi.width / 8 + p * hi.width / 7, y = hi.height / 9 + p * hi.height / 8;
        for (int k = 0; k < 4; k++) {
            double f;
            s = tb_lit_fraction(asset, x, y, suns[k], &f);
            if (s == TB_NO_LAYER) {
                printf("lit unavailable\n");
                lit = 0;
                break;
            }
            check(s, "lit fraction");
            printf("lit %u,%u sun %d %016llx\n", x, y, k, f64_bits(f));
        }
    }

    tb_close(asset);
    tb_close(NULL);
    return 0;
}
