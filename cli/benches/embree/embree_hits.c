// Traces a vkrt .rays file with Embree 3 (rtcIntersect1, tfar as given: +inf is unbounded)
// and compares with a vkrt hits file: hit counts and per-ray agreement.
// cc -O2 embree_hits.c -lembree3 -o embree_hits; [EMBREE_ROBUST=1] ./embree_hits MESH.obj RAYS [HITS]
#include <embree3/rtcore.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + t.tv_nsec * 1e-9; }

int main(int argc, char **argv) {
    if (argc < 3) { fprintf(stderr, "usage: %s MESH.obj RAYS [HITS]\n", argv[0]); return 2; }
    FILE *f = fopen(argv[1], "r");
    if (!f) { perror(argv[1]); return 1; }
    size_t nv = 0, cv = 1 << 20, nt = 0, ct = 1 << 20;
    float *v = malloc(cv * 12); unsigned *t = malloc(ct * 12);
    char line[512];
    while (fgets(line, sizeof line, f)) {
        if (line[0] == 'v' && line[1] == ' ') {
            if (nv == cv) v = realloc(v, (cv *= 2) * 12);
            sscanf(line + 2, "%f %f %f", &v[3 * nv], &v[3 * nv + 1], &v[3 * nv + 2]); nv++;
        } else if (line[0] == 'f' && line[1] == ' ') {
            long idx[64]; int k = 0; char *p = line + 2;
            while (*p && k < 64) {
                while (*p == ' ' || *p == '\t') p++;
                if (!*p || *p == '\n' || *p == '\r') break;
                long x = strtol(p, &p, 10); idx[k++] = x < 0 ? (long)nv + x : x - 1;
                while (*p && *p != ' ' && *p != '\t' && *p != '\n') p++;
            }
            for (int j = 1; j + 1 < k; j++) {
                if (nt == ct) t = realloc(t, (ct *= 2) * 12);
                t[3 * nt] = idx[0]; t[3 * nt + 1] = idx[j]; t[3 * nt + 2] = idx[j + 1]; nt++;
            }
        }
    }
    fclose(f);
    FILE *rf = fopen(argv[2], "rb"); fseek(rf, 0, SEEK_END); long bytes = ftell(rf); fseek(rf, 0, SEEK_SET);
    size_t nr = bytes / 32; float *rays = malloc(bytes); fread(rays, 1, bytes, rf); fclose(rf);
    RTCDevice dev = rtcNewDevice("threads=2");
    double t0 = now();
    RTCScene scene = rtcNewScene(dev);
    rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_MEDIUM);
    // EMBREE_ROBUST=1: Embree's watertight mode (no ray slips between triangles sharing an
    // edge, as vkrt's watertight test); by default Embree trades that for speed.
    const char *robust = getenv("EMBREE_ROBUST");
    if (robust && robust[0] == '1') rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, v, 0, 12, nv);
    rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, t, 0, 12, nt);
    rtcCommitGeometry(g); rtcAttachGeometry(scene, g); rtcReleaseGeometry(g); rtcCommitScene(scene);
    double t1 = now();
    struct RTCIntersectContext ctx; rtcInitIntersectContext(&ctx);
    uint32_t *prim = malloc(nr * 4); size_t hits = 0;
    for (size_t i = 0; i < nr; i++) {
        float *r = rays + 8 * i; struct RTCRayHit rh;
        rh.ray.org_x = r[0]; rh.ray.org_y = r[1]; rh.ray.org_z = r[2]; rh.ray.tnear = r[3];
        rh.ray.dir_x = r[4]; rh.ray.dir_y = r[5]; rh.ray.dir_z = r[6]; rh.ray.tfar = r[7];
        rh.ray.time = 0; rh.ray.mask = -1; rh.ray.id = 0; rh.ray.flags = 0;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID; rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(scene, &ctx, &rh);
        prim[i] = rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? 0xffffffffu : rh.hit.primID;
        hits += prim[i] != 0xffffffffu;
    }
    double t2 = now();
    printf("embree %s: %zu triangles, %zu rays, %zu hits; build %.1f ms, trace %.1f ms (%.2f Mrays/s, 1 thread)\n",
           RTC_VERSION_STRING, nt, nr, hits, (t1 - t0) * 1e3, (t2 - t1) * 1e3, nr / (t2 - t1) / 1e6);
    if (argc > 3) {
        FILE *hf = fopen(argv[3], "rb"); size_t same_hit = 0, same_prim = 0, only_embree = 0, only_vkrt = 0;
        for (size_t i = 0; i < nr; i++) {
            float h[4]; fread(h, 4, 4, hf); uint32_t p; memcpy(&p, &h[1], 4);
            int a = prim[i] != 0xffffffffu, b = p != 0xffffffffu;
            same_hit += a == b; same_prim += prim[i] == p; only_embree += a && !b; only_vkrt += b && !a;
        }
        printf("vs %s: hit/miss agree on %zu of %zu rays (hit by Embree only: %zu, by vkrt only: %zu); same primitive on %zu\n",
               argv[3], same_hit, nr, only_embree, only_vkrt, same_prim);
    }
    return 0;
}
