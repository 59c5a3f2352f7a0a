// Embree 3 as the CPU peer of `cargo bench --bench trace` and `--bench bvh_build`: builds
// its BVH over a triangle file (9 little-endian f32 per triangle) and traces vkrt .rays
// files (8 f32 per ray: ox oy oz tmin dx dy dz tmax) with the single-ray API
// (rtcIntersect1 / rtcOccluded1) on THREADS threads, best of 3 runs.
//
//   cc -O2 embree_trace.c -lembree3 -lpthread -o embree_trace
//   ./embree_trace TRIS THREADS [RAYS:closest|any ...]
//
// Prints `build_ms <ms>` (rtcCommitScene, medium quality, best of 3), then per ray file
// `trace <file> <rays> <hits> <ms>`.
//
// With EMBREE_INSTANCES=FILE (12 little-endian f32 per instance: a row-major 3x4
// object-to-world transform) the triangles become one scene instanced that many times
// (RTC_GEOMETRY_TYPE_INSTANCE) under a top-level scene: `build_ms` is then the top level's
// commit (the instances' boxes and BVH), and `blas_ms` the mesh's.
#include <embree3/rtcore.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + t.tv_nsec * 1e-9;
}

static float *read_floats(const char *path, long *count) {
    FILE *f = fopen(path, "rb");
    if (!f) { perror(path); exit(1); }
    fseek(f, 0, SEEK_END);
    long bytes = ftell(f);
    fseek(f, 0, SEEK_SET);
    float *data = malloc(bytes > 0 ? bytes : 4);
    if (fread(data, 1, bytes, f) != (size_t)bytes) { perror(path); exit(1); }
    fclose(f);
    *count = bytes / 4;
    return data;
}

struct job {
    RTCScene scene;
    const float *rays;
    long first, last;
    int any;
    long hits;
};

static void *trace(void *arg) {
    struct job *j = arg;
    struct RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    long hits = 0;
    for (long i = j->first; i < j->last; i++) {
        const float *r = j->rays + 8 * i;
        struct RTCRayHit rh;
        rh.ray.org_x = r[0]; rh.ray.org_y = r[1]; rh.ray.org_z = r[2]; rh.ray.tnear = r[3];
        rh.ray.dir_x = r[4]; rh.ray.dir_y = r[5]; rh.ray.dir_z = r[6]; rh.ray.tfar = r[7];
        rh.ray.time = 0; rh.ray.mask = -1; rh.ray.id = 0; rh.ray.flags = 0;
        if (j->any) {
            rtcOccluded1(j->scene, &ctx, &rh.ray);
            hits += rh.ray.tfar < 0; // occluded: tfar = -inf
        } else {
            rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
            rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
            rtcIntersect1(j->scene, &ctx, &rh);
            hits += rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
        }
    }
    j->hits = hits;
    return NULL;
}

static RTCScene build(RTCDevice dev, const float *tris, long n, double *ms) {
    RTCScene scene = rtcNewScene(dev);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *v = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                       3 * sizeof(float), 3 * n);
    unsigned *ix = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(unsigned), n);
    memcpy(v, tris, 36 * n);
    for (long i = 0; i < 3 * n; i++) ix[i] = (unsigned)i;
    rtcCommitGeometry(g);
    rtcAttachGeometry(scene, g);
    rtcReleaseGeometry(g);
    double t = now();
    rtcCommitScene(scene);
    *ms = (now() - t) * 1e3;
    return scene;
}

// A top-level scene over `n` instances of `mesh`, transforms `xf` (12 floats each).
static RTCScene build_instances(RTCDevice dev, RTCScene mesh, const float *xf, long n,
                                double *ms) {
    RTCScene scene = rtcNewScene(dev);
    for (long i = 0; i < n; i++) {
        RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(g, mesh);
        rtcSetGeometryTransform(g, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, xf + 12 * i);
        rtcCommitGeometry(g);
        rtcAttachGeometry(scene, g);
        rtcReleaseGeometry(g);
    }
    double t = now();
    rtcCommitScene(scene);
    *ms = (now() - t) * 1e3;
    return scene;
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: %s TRIS THREADS [RAYS:closest|any ...]\n", argv[0]);
        return 2;
    }
    long nf;
    float *tris = read_floats(argv[1], &nf);
    long n = nf / 9;
    int threads = atoi(argv[2]);
    char config[64];
    snprintf(config, sizeof config, "threads=%d", threads);
    RTCDevice dev = rtcNewDevice(config);
    double best = INFINITY, ms;
    RTCScene scene = NULL;
    for (int k = 0; k < 3; k++) {
        if (scene) rtcReleaseScene(scene);
        scene = build(dev, tris, n, &ms);
        if (ms < best) best = ms;
    }
    const char *inst_path = getenv("EMBREE_INSTANCES");
    if (inst_path && *inst_path) {
        long nx;
        float *xf = read_floats(inst_path, &nx);
        printf("blas_ms %.3f\n", best);
        RTCScene mesh = scene;
        scene = NULL;
        best = INFINITY;
        for (int k = 0; k < 3; k++) {
            if (scene) rtcReleaseScene(scene);
            scene = build_instances(dev, mesh, xf, nx / 12, &ms);
            if (ms < best) best = ms;
        }
        rtcReleaseScene(mesh); // the instances keep it
        free(xf);
    }
    printf("build_ms %.3f\n", best);
    for (int a = 3; a < argc; a++) {
        char path[4096];
        snprintf(path, sizeof path, "%s", argv[a]);
        char *kind = strrchr(path, ':');
        if (!kind) { fprintf(stderr, "%s: want RAYS:closest or RAYS:any\n", argv[a]); return 2; }
        *kind++ = 0;
        long nr;
        float *rays = read_floats(path, &nr);
        nr /= 8;
        double best_trace = INFINITY;
        long hits = 0;
        for (int k = 0; k < 3; k++) {
            pthread_t th[64];
            struct job jobs[64];
            int t_n = threads < 1 ? 1 : threads > 64 ? 64 : threads;
            double t0 = now();
            for (int t = 0; t < t_n; t++) {
                jobs[t] = (struct job){scene, rays, nr * t / t_n, nr * (t + 1) / t_n,
                                       strcmp(kind, "any") == 0, 0};
                pthread_create(&th[t], NULL, trace, &jobs[t]);
            }
            hits = 0;
            for (int t = 0; t < t_n; t++) {
                pthread_join(th[t], NULL);
                hits += jobs[t].hits;
            }
            double dt = (now() - t0) * 1e3;
            if (dt < best_trace) best_trace = dt;
        }
        printf("trace %s %ld %ld %.3f\n", path, nr, hits, best_trace);
        free(rays);
    }
    rtcReleaseScene(scene);
    rtcReleaseDevice(dev);
    free(tris);
    return 0;
}
