/* The Embree 3 side of trevi-bench: builds the mesh trevi-bench wrote and
 * traces the rays it wrote, on the same number of threads, and prints
 *
 *   scene_build <seconds> <CPU seconds> <bytes of the scene: Embree's + mesh>
 *   bvh2_build <seconds> <CPU seconds> <SAH cost>
 *   <ray type> <rays> <hits> <seconds> <CPU seconds of the tracing threads>
 *
 * usage: embree_bench THREADS MESH PRIMARY.rays SHADOW.rays INCOHERENT.rays
 *
 * scene_build is rtcCommitScene on a default (medium quality) scene: the
 * structure the traversal figures use. bvh2_build runs Embree's binned-SAH
 * builder (rtcBuildBVH) with Trevi's parameters (binary, leaves of at most 4,
 * traversal and intersection cost 1) so the SAH costs of the two trees are
 * comparable; it is timed separately. Ray files named *shadow* are traced
 * with rtcOccluded1, the others with rtcIntersect1. File formats: see
 * bench/src/main.rs. */
#define _GNU_SOURCE
#include <embree3/rtcore.h>
typedef struct RTCBounds RTCBounds;
typedef struct RTCBuildPrimitive RTCBuildPrimitive;
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static double process_cpu(void) {
  struct timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void *read_file(const char *path, size_t *len) {
  FILE *f = fopen(path, "rb");
  if (!f) {
    perror(path);
    exit(1);
  }
  fseek(f, 0, SEEK_END);
  *len = (size_t)ftell(f);
  fseek(f, 0, SEEK_SET);
  /* 16 spare bytes: Embree may read a vertex buffer with 16-byte loads. */
  void *buf = calloc(1, *len + 16);
  if (fread(buf, 1, *len, f) != *len) {
    perror(path);
    exit(1);
  }
  fclose(f);
  return buf;
}

static _Atomic long long allocated = 0;
static bool monitor(void *user, ssize_t bytes, bool post) {
  (void)user;
  (void)post;
  allocated += bytes;
  return true;
}

/* ---- SAH cost of Embree's binary binned-SAH build (rtcBuildBVH) ---- */

typedef struct Node {
  int count; /* 0: inner node; > 0: leaf of that many primitives */
  struct Node *child[2];
  double area[2]; /* children's half areas */
} Node;

static double root_area;


static double half_area(const RTCBounds *b) {
  double dx = b->upper_x - b->lower_x, dy = b->upper_y - b->lower_y,
         dz = b->upper_z - b->lower_z;
  return dx * dy + dy * dz + dz * dx;
}


static void *create_node(RTCThreadLocalAllocator alloc, unsigned int n, void *user) {
  (void)user;
  (void)n;
  Node *node = rtcThreadLocalAlloc(alloc, sizeof(Node), 16);
  node->count = 0;
  node->area[0] = node->area[1] = 0;
  node->child[0] = node->child[1] = NULL;
  return node;
}

static void set_children(void *node, void **children, unsigned int n, void *user) {
  (void)user;
  for (unsigned int i = 0; i < n && i < 2; i++)
    ((Node *)node)->child[i] = children[i];
}

static void set_bounds(void *node, const RTCBounds **bounds, unsigned int n, void *user) {
  (void)user;
  for (unsigned int i = 0; i < n && i < 2; i++)
    ((Node *)node)->area[i] = half_area(bounds[i]);
}

/* Sum over the children of inner nodes of area × (1 or leaf size). */
static double sah_of(const Node *node) {
  double s = 0;
  if (node->count > 0)
    return 0;
  for (int i = 0; i < 2; i++) {
    const Node *c = node->child[i];
    if (!c)
      continue;
    s += (c->count > 0 ? c->count : 1) * node->area[i] / root_area;
    s += sah_of(c);
  }
  return s;
}

static void *create_leaf(RTCThreadLocalAllocator alloc, const RTCBuildPrimitive *prims,
                         size_t n, void *user) {
  (void)user;
  (void)prims;
  Node *leaf = rtcThreadLocalAlloc(alloc, sizeof(Node), 16);
  leaf->count = (int)n;
  leaf->child[0] = leaf->child[1] = NULL;
  return leaf;
}

/* ---- traversal ---- */

typedef struct {
  RTCScene scene;
  const float *rays; /* 7 floats per ray */
  size_t count;
  int occluded;
  _Atomic size_t next;
  _Atomic size_t hits;
  _Atomic long long cpu_ns; /* CPU time of the tracing threads */
} Job;

#define CHUNK 256

static double thread_cpu(void) {
  struct timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void *worker(void *arg) {
  Job *job = arg;
  double c0 = thread_cpu();
  struct RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  size_t hits = 0;
  for (;;) {
    size_t start = atomic_fetch_add(&job->next, CHUNK);
    if (start >= job->count)
      break;
    size_t end = start + CHUNK < job->count ? start + CHUNK : job->count;
    for (size_t i = start; i < end; i++) {
      const float *r = job->rays + 7 * i;
      if (job->occluded) {
        struct RTCRay ray;
        ray.org_x = r[0];
        ray.org_y = r[1];
        ray.org_z = r[2];
        ray.dir_x = r[3];
        ray.dir_y = r[4];
        ray.dir_z = r[5];
        ray.tnear = 0.0f;
        ray.tfar = r[6];
        ray.time = 0.0f;
        ray.mask = 0xffffffff;
        ray.id = 0;
        ray.flags = 0;
        rtcOccluded1(job->scene, &ctx, &ray);
        hits += ray.tfar < 0.0f; /* -inf when occluded */
      } else {
        struct RTCRayHit rh;
        rh.ray.org_x = r[0];
        rh.ray.org_y = r[1];
        rh.ray.org_z = r[2];
        rh.ray.dir_x = r[3];
        rh.ray.dir_y = r[4];
        rh.ray.dir_z = r[5];
        rh.ray.tnear = 0.0f;
        rh.ray.tfar = r[6];
        rh.ray.time = 0.0f;
        rh.ray.mask = 0xffffffff;
        rh.ray.id = 0;
        rh.ray.flags = 0;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(job->scene, &ctx, &rh);
        hits += rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
      }
    }
  }
  atomic_fetch_add(&job->hits, hits);
  atomic_fetch_add(&job->cpu_ns, (long long)((thread_cpu() - c0) * 1e9));
  return NULL;
}

int main(int argc, char **argv) {
  if (argc < 3) {
    fprintf(stderr, "usage: %s THREADS MESH [RAYS...]\n", argv[0]);
    return 2;
  }
  int threads = atoi(argv[1]);
  char config[64];
  snprintf(config, sizeof config, "threads=%d,set_affinity=0", threads);
  RTCDevice device = rtcNewDevice(config);
  if (!device) {
    fprintf(stderr, "rtcNewDevice failed\n");
    return 1;
  }
  rtcSetDeviceMemoryMonitorFunction(device, monitor, NULL);

  size_t len;
  uint8_t *mesh = read_file(argv[2], &len);
  uint32_t nv, nt;
  memcpy(&nv, mesh, 4);
  memcpy(&nt, mesh + 4, 4);
  float *verts = (float *)(mesh + 8);
  uint32_t *tris = (uint32_t *)(mesh + 8 + 12 * (size_t)nv);

  /* The scene used for traversal. Shared buffers: the mesh is not copied.
   * Built twice, the first time only to start Embree's and TBB's threads and
   * allocators; the second build is the one timed. */
  RTCScene scene = NULL;
  long long bytes = 0;
  double t_scene = 0, c_scene = 0;
  for (int pass = 0; pass < 2; pass++) {
    if (scene)
      rtcReleaseScene(scene);
    long long before = allocated;
    double t0 = now(), c0 = process_cpu();
    scene = rtcNewScene(device);
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, verts, 0,
                               12, nv);
    rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, tris, 0,
                               12, nt);
    rtcCommitGeometry(geom);
    rtcAttachGeometry(scene, geom);
    rtcReleaseGeometry(geom);
    rtcCommitScene(scene);
    t_scene = now() - t0;
    c_scene = process_cpu() - c0;
    bytes = allocated - before + 12LL * nv + 12LL * nt;
  }
  printf("scene_build %.6f %.6f %lld\n", t_scene, c_scene, bytes);

  /* Embree's binary SAH builder on the same triangle boxes. */
  RTCBuildPrimitive *prims = malloc(sizeof(RTCBuildPrimitive) * nt);
  RTCBounds root = {INFINITY, INFINITY, INFINITY, 0, -INFINITY, -INFINITY, -INFINITY, 0};
  for (uint32_t i = 0; i < nt; i++) {
    RTCBuildPrimitive *p = &prims[i];
    p->lower_x = p->lower_y = p->lower_z = INFINITY;
    p->upper_x = p->upper_y = p->upper_z = -INFINITY;
    for (int k = 0; k < 3; k++) {
      const float *v = verts + 3 * (size_t)tris[3 * (size_t)i + k];
      p->lower_x = fminf(p->lower_x, v[0]);
      p->lower_y = fminf(p->lower_y, v[1]);
      p->lower_z = fminf(p->lower_z, v[2]);
      p->upper_x = fmaxf(p->upper_x, v[0]);
      p->upper_y = fmaxf(p->upper_y, v[1]);
      p->upper_z = fmaxf(p->upper_z, v[2]);
    }
    p->geomID = 0;
    p->primID = i;
    root.lower_x = fminf(root.lower_x, p->lower_x);
    root.lower_y = fminf(root.lower_y, p->lower_y);
    root.lower_z = fminf(root.lower_z, p->lower_z);
    root.upper_x = fmaxf(root.upper_x, p->upper_x);
    root.upper_y = fmaxf(root.upper_y, p->upper_y);
    root.upper_z = fmaxf(root.upper_z, p->upper_z);
  }
  root_area = half_area(&root);
  RTCBVH bvh = rtcNewBVH(device);
  struct RTCBuildArguments a = rtcDefaultBuildArguments();
  a.byteSize = sizeof(a);
  a.buildQuality = RTC_BUILD_QUALITY_MEDIUM;
  a.maxBranchingFactor = 2;
  a.maxDepth = 1024;
  a.sahBlockSize = 1;
  a.minLeafSize = 1;
  a.maxLeafSize = 4;
  a.traversalCost = 1.0f;
  a.intersectionCost = 1.0f;
  a.bvh = bvh;
  a.primitives = prims;
  a.primitiveCount = nt;
  a.primitiveArrayCapacity = nt;
  a.createNode = create_node;
  a.setNodeChildren = set_children;
  a.setNodeBounds = set_bounds;
  a.createLeaf = create_leaf;
  a.splitPrimitive = NULL;
  a.buildProgress = NULL;
  a.userPtr = NULL;
  double t0 = now(), c0 = process_cpu();
  Node *bvh_root = rtcBuildBVH(&a);
  double t_bvh = now() - t0, c_bvh = process_cpu() - c0;
  /* The root counts once, as an inner node (or as a leaf of its size). */
  double sah = bvh_root->count > 0 ? bvh_root->count : 1.0 + sah_of(bvh_root);
  printf("bvh2_build %.6f %.6f %.3f\n", t_bvh, c_bvh, sah);
  rtcReleaseBVH(bvh);
  free(prims);


  for (int f = 3; f < argc; f++) {
    size_t rlen;
    uint8_t *raw = read_file(argv[f], &rlen);
    uint32_t n;
    memcpy(&n, raw, 4);
    const char *base = strrchr(argv[f], '/');
    base = base ? base + 1 : argv[f];
    /* "<mesh>.<type>.rays" */
    char type[64];
    const char *dot2 = strrchr(base, '.');
    const char *dot1 = dot2;
    while (dot1 > base && dot1[-1] != '.')
      dot1--;
    snprintf(type, sizeof type, "%.*s", (int)(dot2 - dot1), dot1);
    Job job = {scene, (const float *)(raw + 4), n, strstr(type, "shadow") != NULL, 0, 0, 0};
    pthread_t th[64];
    int nth = threads < 64 ? threads : 64;
    t0 = now();
    for (int i = 0; i < nth; i++)
      pthread_create(&th[i], NULL, worker, &job);
    for (int i = 0; i < nth; i++)
      pthread_join(th[i], NULL);
    double t = now() - t0;
    printf("%s %u %zu %.6f %.6f\n", type, n, (size_t)job.hits, t, job.cpu_ns * 1e-9);
    free(raw);
  }
  rtcReleaseScene(scene);
  rtcReleaseDevice(device);
  free(mesh);
  return 0;
}
