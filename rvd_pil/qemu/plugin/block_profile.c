/*
 * rvd block_profile: a QEMU TCG plugin (user mode) that counts how often each translation block
 * executes inside the solve markers of rvd::SolveMarker (flight_sw/app/solve_marker.hpp), and
 * optionally runs a two-level cache model (L1D + L1I + unified L2) over the guest's accesses. The
 * cycle model (rvd_pil/qemu/cycles.py) prices each block once per executable and sums count x cost.
 *
 * It shares the marker ABI with insn_count.c (syscall RVD_MARKER_NR, op 1 = begin, 2 = end; op 3,
 * the flight clock's read, is ignored here) but never touches the guest's slot: run it beside
 * insn_count, which answers the guest (every flight run does: rvd-run --target, make pil). Counting is
 * the same as insn_count's inline mode (one inline add per executed block, at block entry), so the
 * instructions of a region, sum over blocks of count x block size, equal insn_count's figure.
 *
 * Arguments:
 *   out=PATH                 output file (required)
 *   cache=off|on|process     run the cache model (default off; costs a callback per access):
 *                            on: over the solve regions only, process: over every access
 *   l1d=SIZE:WAYS:LINE       geometry in bytes, e.g. 32768:4:64 (defaults: Cortex-A53)
 *   l1i=SIZE:WAYS:LINE
 *   l2=SIZE:WAYS:LINE
 *
 * Output (text, one record per line; every number decimal unless marked hex):
 *   B id vaddr_hex n_insns bytes_hex     a block, written once, before the first record using it
 *   R step insns <cache counters>        a solve region (end marker), then its block counts in
 *   C id:count id:count ...              one line (only blocks that ran in the region)
 *   P 0 insns <cache counters>           the whole process, at exit, then its C line (its cache
 *                                        counters: what the model saw, the solves with cache=on)
 *   M id load_l1 load_l2 store_l1 store_l2 ifetch_l1 ifetch_l2
 *                                        (cache on) each block's misses inside the solve regions, at
 *                                        exit: per-block miss rates for runs without the cache model
 * Cache counters (11 numbers): load_accesses load_l1_misses load_l2_misses store_accesses
 *   store_l1_misses store_l2_misses ifetch_lines ifetch_l1_misses ifetch_l2_misses
 *   l2_writebacks l1_writebacks
 * Identical code translated twice (a flushed and retranslated block) shares one id: blocks are
 * keyed by address and bytes.
 *
 * Why cache=on models the solves only: the code between two solves waits for the host (its poll
 * and receive loops run as often as the host's timing makes them, its clock reads and divisions
 * take value-dependent paths), so the cache state it would leave differs from run to run, and so
 * would the next solve's misses. With the model blind between the solves, a solve starts from the
 * state the previous solve left, a function of the solves alone. cache=process (a board
 * calibration, which compares the whole process with perf) models everything.
 */
#include <inttypes.h>
#include <pthread.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <qemu-plugin.h>

QEMU_PLUGIN_EXPORT int qemu_plugin_version = QEMU_PLUGIN_VERSION;

#define RVD_MARKER_NR 0x5256
#define RVD_MARKER_BEGIN 1
#define RVD_MARKER_END 2
#define CHUNK 4096          /* blocks per allocation chunk: counters never move */
#define MAX_CHUNKS 4096     /* 16 M distinct blocks */
#define MAX_BLOCK_BYTES 4096

/* One distinct block. `count` is bumped inline by every translation of it. */
struct block {
  uint64_t count;
  uint64_t mark;     /* count at the last begin marker */
  uint64_t vaddr;
  uint32_t n_insns;
  uint32_t n_bytes;
  uint32_t id;
  uint32_t hash;
  bool written;      /* its B line is in the output */
  uint8_t *bytes;
  uint64_t miss[6];  /* cache on: load L1, load L2, store L1, store L2, ifetch L1, ifetch L2 */
};

static struct block *chunks[MAX_CHUNKS];
static uint32_t n_blocks;
static uint32_t *table;  /* open addressing: block id + 1, 0 = empty */
static uint32_t table_size;
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static FILE *out;
static bool in_region;
static uint32_t region_step;

static struct block *block_at(uint32_t id) { return &chunks[id / CHUNK][id % CHUNK]; }

/* ---- cache model -------------------------------------------------------------------------- */
/* Set-associative, LRU, write-back, write-allocate. Virtual addresses (user mode has no physical
 * ones); replacement is LRU for every level (the real cores use pseudo-random or pseudo-LRU). */
struct cache {
  uint64_t *tags;    /* sets x ways; 0 = invalid, else line address + 1 */
  uint64_t *stamp;   /* last use, for LRU */
  uint8_t *dirty;
  uint32_t sets, ways, line_shift;
  uint64_t clock;
};

struct cache_stats {
  uint64_t load_acc, load_l1_miss, load_l2_miss;
  uint64_t store_acc, store_l1_miss, store_l2_miss;
  uint64_t ifetch_lines, ifetch_l1_miss, ifetch_l2_miss;
  uint64_t l2_writebacks, l1_writebacks;
};

static bool cache_on;
static bool cache_whole_process;  /* cache=process; else the model sees the solve regions only */
static struct cache l1d, l1i, l2;
static struct cache_stats stats, stats_mark;
static unsigned geom_l1d[3] = {32768, 4, 64}, geom_l1i[3] = {32768, 2, 64}, geom_l2[3] = {524288, 16, 64};

static bool cache_init(struct cache *c, const unsigned g[3]) {
  unsigned size = g[0], ways = g[1], line = g[2];
  if (!size || !ways || !line || (line & (line - 1)) || size % (ways * line)) return false;
  c->sets = size / (ways * line);
  c->ways = ways;
  c->line_shift = (uint32_t)__builtin_ctz(line);
  c->tags = calloc((size_t)c->sets * ways, sizeof *c->tags);
  c->stamp = calloc((size_t)c->sets * ways, sizeof *c->stamp);
  c->dirty = calloc((size_t)c->sets * ways, 1);
  return c->tags && c->stamp && c->dirty;
}

/* Looks up (and on a miss fills) the line holding `addr`. Returns true on a hit. *evicted_dirty
 * tells whether the fill pushed out a dirty line. */
static bool cache_access(struct cache *c, uint64_t addr, bool write, bool *evicted_dirty) {
  uint64_t line = addr >> c->line_shift;
  uint32_t set = (uint32_t)(line % c->sets);
  uint64_t *tags = c->tags + (size_t)set * c->ways;
  uint64_t *stamp = c->stamp + (size_t)set * c->ways;
  uint8_t *dirty = c->dirty + (size_t)set * c->ways;
  uint64_t key = line + 1;
  c->clock++;
  uint32_t victim = 0;
  for (uint32_t w = 0; w < c->ways; w++) {
    if (tags[w] == key) {
      stamp[w] = c->clock;
      if (write) dirty[w] = 1;
      *evicted_dirty = false;
      return true;
    }
    if (stamp[w] < stamp[victim]) victim = w;
  }
  *evicted_dirty = tags[victim] != 0 && dirty[victim];
  tags[victim] = key;
  stamp[victim] = c->clock;
  dirty[victim] = write;
  return false;
}

/* One data access of one line: L1D, then L2 on a miss; misses also charged to the block. */
static void data_line(uint64_t addr, bool store, uint64_t *block_miss) {
  bool wb;
  if (store) stats.store_acc++; else stats.load_acc++;
  if (cache_access(&l1d, addr, store, &wb)) return;
  if (wb) stats.l1_writebacks++;
  if (store) stats.store_l1_miss++; else stats.load_l1_miss++;
  if (in_region) block_miss[store ? 2 : 0]++;
  bool wb2;
  if (!cache_access(&l2, addr, false, &wb2)) {
    if (store) stats.store_l2_miss++; else stats.load_l2_miss++;
    if (in_region) block_miss[store ? 3 : 1]++;
  }
  if (wb2) stats.l2_writebacks++;
}

static void on_mem(unsigned int vcpu_index, qemu_plugin_meminfo_t info, uint64_t vaddr, void *udata) {
  (void)vcpu_index;
  if (!in_region && !cache_whole_process) return;
  unsigned size = 1u << qemu_plugin_mem_size_shift(info);
  bool store = qemu_plugin_mem_is_store(info);
  uint64_t first = vaddr >> l1d.line_shift, last = (vaddr + size - 1) >> l1d.line_shift;
  for (uint64_t l = first; l <= last; l++) data_line(l << l1d.line_shift, store, (uint64_t *)udata);
}

static void on_tb_exec(unsigned int vcpu_index, void *udata) {
  (void)vcpu_index;
  if (!in_region && !cache_whole_process) return;
  struct block *b = udata;
  uint64_t first = b->vaddr >> l1i.line_shift, last = (b->vaddr + b->n_bytes - 1) >> l1i.line_shift;
  for (uint64_t l = first; l <= last; l++) {
    bool wb;
    stats.ifetch_lines++;
    if (cache_access(&l1i, l << l1i.line_shift, false, &wb)) continue;
    stats.ifetch_l1_miss++;
    if (in_region) b->miss[4]++;
    bool wb2;
    if (!cache_access(&l2, l << l1i.line_shift, false, &wb2)) {
      stats.ifetch_l2_miss++;
      if (in_region) b->miss[5]++;
    }
    if (wb2) stats.l2_writebacks++;
  }
}

/* ---- blocks ------------------------------------------------------------------------------- */
static uint32_t fnv1a(const uint8_t *p, size_t n, uint64_t seed) {
  uint32_t h = 2166136261u ^ (uint32_t)seed ^ (uint32_t)(seed >> 32);
  for (size_t i = 0; i < n; i++) h = (h ^ p[i]) * 16777619u;
  return h;
}

static bool table_grow(void) {
  uint32_t size = table_size ? table_size * 2 : 1u << 16;
  uint32_t *t = calloc(size, sizeof *t);
  if (!t) return false;
  for (uint32_t id = 0; id < n_blocks; id++) {
    uint32_t i = block_at(id)->hash & (size - 1);
    while (t[i]) i = (i + 1) & (size - 1);
    t[i] = id + 1;
  }
  free(table);
  table = t;
  table_size = size;
  return true;
}

/* The block with these bytes at this address, created if new; NULL when out of memory. */
static struct block *intern(uint64_t vaddr, uint32_t n_insns, const uint8_t *bytes, uint32_t n_bytes) {
  uint32_t h = fnv1a(bytes, n_bytes, vaddr);
  if ((n_blocks + 1) * 2 > table_size && !table_grow()) return NULL;
  uint32_t i = h & (table_size - 1);
  for (; table[i]; i = (i + 1) & (table_size - 1)) {
    struct block *b = block_at(table[i] - 1);
    if (b->hash == h && b->vaddr == vaddr && b->n_insns == n_insns && b->n_bytes == n_bytes &&
        memcmp(b->bytes, bytes, n_bytes) == 0)
      return b;
  }
  uint32_t id = n_blocks;
  if (id / CHUNK >= MAX_CHUNKS) return NULL;
  if (!chunks[id / CHUNK] && !(chunks[id / CHUNK] = calloc(CHUNK, sizeof(struct block)))) return NULL;
  struct block *b = block_at(id);
  b->bytes = malloc(n_bytes);
  if (!b->bytes) return NULL;
  memcpy(b->bytes, bytes, n_bytes);
  b->vaddr = vaddr, b->n_insns = n_insns, b->n_bytes = n_bytes, b->id = id, b->hash = h;
  n_blocks++;
  table[i] = id + 1;
  return b;
}

static void on_tb_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
  (void)id;
  size_t n = qemu_plugin_tb_n_insns(tb);
  if (n == 0) return;
  uint8_t bytes[MAX_BLOCK_BYTES];
  uint32_t n_bytes = 0;
  for (size_t i = 0; i < n; i++) {
    struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
    size_t sz = qemu_plugin_insn_size(insn);
    if (n_bytes + sz <= sizeof bytes) memcpy(bytes + n_bytes, qemu_plugin_insn_data(insn), sz);
    n_bytes += (uint32_t)sz;
  }
  if (n_bytes > sizeof bytes) {
    fprintf(stderr, "rvd block_profile: block at 0x%" PRIx64 " longer than %d bytes\n",
            qemu_plugin_tb_vaddr(tb), MAX_BLOCK_BYTES);
    abort();
  }
  pthread_mutex_lock(&lock);
  struct block *b = intern(qemu_plugin_tb_vaddr(tb), (uint32_t)n, bytes, n_bytes);
  pthread_mutex_unlock(&lock);
  if (!b) {
    fprintf(stderr, "rvd block_profile: out of memory for blocks\n");
    abort();
  }
  if (cache_on)
    for (size_t i = 0; i < n; i++)
      qemu_plugin_register_vcpu_mem_cb(qemu_plugin_tb_get_insn(tb, i), on_mem, QEMU_PLUGIN_CB_NO_REGS,
                                       QEMU_PLUGIN_MEM_RW, b->miss);
  qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &b->count, 1);
  if (cache_on) qemu_plugin_register_vcpu_tb_exec_cb(tb, on_tb_exec, QEMU_PLUGIN_CB_NO_REGS, b);
}

static void write_stats(const struct cache_stats *s, const struct cache_stats *m) {
  fprintf(out, " %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64
               " %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64,
          s->load_acc - m->load_acc, s->load_l1_miss - m->load_l1_miss, s->load_l2_miss - m->load_l2_miss,
          s->store_acc - m->store_acc, s->store_l1_miss - m->store_l1_miss,
          s->store_l2_miss - m->store_l2_miss, s->ifetch_lines - m->ifetch_lines,
          s->ifetch_l1_miss - m->ifetch_l1_miss, s->ifetch_l2_miss - m->ifetch_l2_miss,
          s->l2_writebacks - m->l2_writebacks, s->l1_writebacks - m->l1_writebacks);
}

/* Writes one record: the new blocks' B lines, the header, the C line of every block whose count
 * moved since `since_mark` (false: since the start of the process). */
static void write_record(char kind, uint32_t step, bool since_mark, const struct cache_stats *m) {
  uint64_t insns = 0;
  for (uint32_t id = 0; id < n_blocks; id++) {
    struct block *b = block_at(id);
    uint64_t d = b->count - (since_mark ? b->mark : 0);
    if (!d) continue;
    insns += d * b->n_insns;
    if (!b->written) {
      fprintf(out, "B %u %" PRIx64 " %u ", b->id, b->vaddr, b->n_insns);
      for (uint32_t i = 0; i < b->n_bytes; i++) fprintf(out, "%02x", b->bytes[i]);
      fputc('\n', out);
      b->written = true;
    }
  }
  fprintf(out, "%c %u %" PRIu64, kind, step, insns);
  write_stats(&stats, m);
  fputs("\nC", out);
  for (uint32_t id = 0; id < n_blocks; id++) {
    struct block *b = block_at(id);
    uint64_t d = b->count - (since_mark ? b->mark : 0);
    if (d) fprintf(out, " %u:%" PRIu64, id, d);
  }
  fputc('\n', out);
  fflush(out); /* a killed run keeps every region already written */
}

static void on_syscall(qemu_plugin_id_t id, unsigned int vcpu_index, int64_t num, uint64_t op,
                       uint64_t step, uint64_t slot, uint64_t a4, uint64_t a5, uint64_t a6,
                       uint64_t a7, uint64_t a8) {
  (void)id, (void)vcpu_index, (void)slot, (void)a4, (void)a5, (void)a6, (void)a7, (void)a8;
  if (num != RVD_MARKER_NR) return;
  pthread_mutex_lock(&lock);
  if (op == RVD_MARKER_BEGIN) {
    for (uint32_t i = 0; i < n_blocks; i++) block_at(i)->mark = block_at(i)->count;
    stats_mark = stats;
    in_region = true;
    region_step = (uint32_t)step;
  } else if (op == RVD_MARKER_END && in_region && region_step == (uint32_t)step) {
    write_record('R', region_step, true, &stats_mark);
    in_region = false;
  } else if (op == RVD_MARKER_END) {
    fprintf(out, "# end of step %" PRIu64 " without its begin: ignored\n", step);
  }
  pthread_mutex_unlock(&lock);
}

static void at_exit(qemu_plugin_id_t id, void *userdata) {
  (void)id, (void)userdata;
  pthread_mutex_lock(&lock);
  if (out) {
    static const struct cache_stats zero;
    write_record('P', 0, false, &zero);
    for (uint32_t id = 0; cache_on && id < n_blocks; id++) {
      const struct block *b = block_at(id);
      if (b->miss[0] | b->miss[1] | b->miss[2] | b->miss[3] | b->miss[4] | b->miss[5])
        fprintf(out, "M %u %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64 " %" PRIu64 "\n", id,
                b->miss[0], b->miss[1], b->miss[2], b->miss[3], b->miss[4], b->miss[5]);
    }
    fclose(out);
    out = NULL;
  }
  pthread_mutex_unlock(&lock);
}

static bool parse_geometry(const char *s, unsigned g[3]) {
  return sscanf(s, "%u:%u:%u", &g[0], &g[1], &g[2]) == 3;
}

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info, int argc,
                                           char **argv) {
  if (info->system_emulation) {
    fprintf(stderr, "rvd block_profile: user mode only\n");
    return -1;
  }
  const char *path = NULL;
  for (int i = 0; i < argc; i++) {
    const char *a = argv[i];
    bool ok = true;
    if (strncmp(a, "out=", 4) == 0) path = a + 4;
    else if (strcmp(a, "cache=on") == 0) cache_on = true, cache_whole_process = false;
    else if (strcmp(a, "cache=process") == 0) cache_on = true, cache_whole_process = true;
    else if (strcmp(a, "cache=off") == 0) cache_on = false;
    else if (strncmp(a, "l1d=", 4) == 0) ok = parse_geometry(a + 4, geom_l1d);
    else if (strncmp(a, "l1i=", 4) == 0) ok = parse_geometry(a + 4, geom_l1i);
    else if (strncmp(a, "l2=", 3) == 0) ok = parse_geometry(a + 3, geom_l2);
    else ok = false;
    if (!ok) {
      fprintf(stderr, "rvd block_profile: bad argument '%s' (out=PATH, cache=on|process|off, "
                      "l1d=|l1i=|l2=SIZE:WAYS:LINE)\n", a);
      return -1;
    }
  }
  if (!path) {
    fprintf(stderr, "rvd block_profile: out=PATH is required\n");
    return -1;
  }
  if (cache_on && !(cache_init(&l1d, geom_l1d) && cache_init(&l1i, geom_l1i) && cache_init(&l2, geom_l2))) {
    fprintf(stderr, "rvd block_profile: invalid cache geometry (size = sets x ways x line, line a power of 2)\n");
    return -1;
  }
  out = fopen(path, "w");
  if (!out) {
    fprintf(stderr, "rvd block_profile: cannot open '%s'\n", path);
    return -1;
  }
  fprintf(out, "# rvd block_profile: target %s, cache %s", info->target_name, cache_on ? "on" : "off");
  if (cache_on)
    fprintf(out, " over %s l1d %u:%u:%u l1i %u:%u:%u l2 %u:%u:%u", cache_whole_process ? "process" : "solves",
            geom_l1d[0], geom_l1d[1], geom_l1d[2],
            geom_l1i[0], geom_l1i[1], geom_l1i[2], geom_l2[0], geom_l2[1], geom_l2[2]);
  fputc('\n', out);
  qemu_plugin_register_vcpu_tb_trans_cb(id, on_tb_translate);
  qemu_plugin_register_vcpu_syscall_cb(id, on_syscall);
  qemu_plugin_register_atexit_cb(id, at_exit, NULL);
  return 0;
}
