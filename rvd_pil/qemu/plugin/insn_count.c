/*
 * rvd insn_count: a QEMU TCG plugin (user mode) that counts guest instructions between the solve
 * markers of rvd::SolveMarker (flight_sw/app/solve_marker.hpp) and hands each count back to the
 * guest.
 *
 * Marker ABI, shared with solve_marker.hpp and the flight clock (flight_sw/solver/elapsed.hpp):
 *   syscall(RVD_MARKER_NR, op, step, slot)     op: 1 = begin, 2 = end, 3 = read the counter;
 *                                              slot: guest address of a u64
 * The syscall number is unused by Linux, so the guest kernel (or QEMU's syscall layer) answers
 * ENOSYS; this plugin sees it first. The guest writes SLOT_REQUEST into the slot before each call.
 *   begin: the plugin notes the vCPU's count and writes SLOT_ACK (so the guest knows it is counted).
 *   end:   the plugin writes the instructions executed on that vCPU since its begin.
 *   read:  the plugin writes the vCPU's instruction count so far (the flight clock's ticks: under
 *          emulation the flight times its steps in target time, instructions x CPI / f_clk, instead
 *          of the host's clock). Independent of begin/end, not logged; a slot still holding
 *          SLOT_REQUEST afterwards tells the guest that no plugin is listening.
 * Only this plugin writes slots: block_profile.c runs beside it and stays read-only.
 * The plugin touches the slot only if it holds SLOT_REQUEST: that proves the address translation
 * (host = guest + guest_base, with guest_base = haddr - vaddr of any translated instruction).
 * Every count is also appended to the log file (argument log=PATH) as "step insns" lines.
 *
 * Arguments: log=PATH (optional), count=inline|vcpu.
 *   inline (default) adds each translation block's instruction count to one counter inline
 *          (+1-2 % run time); exact for a single-threaded guest, includes all threads otherwise.
 *   vcpu   a callback per executed block adds to the executing thread's own counter: exact with
 *          threads, slower.
 * The count between begin and end includes the end marker's own few instructions (constant).
 */
#define _GNU_SOURCE /* process_vm_readv */
#include <errno.h>
#include <inttypes.h>
#include <pthread.h>
#include <stdbool.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/uio.h>
#include <unistd.h>

#include <qemu-plugin.h>

QEMU_PLUGIN_EXPORT int qemu_plugin_version = QEMU_PLUGIN_VERSION;

#define RVD_MARKER_NR 0x5256 /* "RV"; Linux leaves it unallocated on arm and aarch64 */
#define RVD_MARKER_BEGIN 1
#define RVD_MARKER_END 2
#define RVD_MARKER_READ 3
#define SLOT_REQUEST UINT64_C(0x525644534c4f543f) /* "RVDSLOT?" */
#define SLOT_ACK UINT64_C(0x525644534c4f5421)     /* "RVDSLOT!" */
#define MAX_VCPUS 256

/* One cache line per vCPU: threads update their own counters without false sharing. */
struct vcpu_state {
  uint64_t insns;       /* vcpu mode: instructions this vCPU executed */
  uint64_t begin_mark;  /* counter value at the last begin marker */
  bool in_region;
  uint32_t begin_step;
  char pad[64 - 2 * sizeof(uint64_t) - sizeof(bool) - sizeof(uint32_t)];
};

static struct vcpu_state vcpus[MAX_VCPUS];
static uint64_t total_insns; /* inline mode: all vCPUs together */
static bool per_vcpu;
static int64_t guest_base; /* host address - guest address; valid once have_guest_base */
static bool have_guest_base;
static unsigned n_vcpus;
static uint64_t n_regions, n_slot_mismatch, n_reads;
static FILE *log_file;
static pthread_mutex_t log_lock = PTHREAD_MUTEX_INITIALIZER;

static void log_line(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static void log_line(const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  pthread_mutex_lock(&log_lock);
  if (log_file) {
    vfprintf(log_file, fmt, ap);
    fflush(log_file); /* a killed run keeps every count already written */
  }
  pthread_mutex_unlock(&log_lock);
  va_end(ap);
}

static void count_tb(unsigned int vcpu_index, void *udata) {
  if (vcpu_index < MAX_VCPUS) vcpus[vcpu_index].insns += (uintptr_t)udata;
}

static void on_tb_translate(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
  (void)id;
  size_t n = qemu_plugin_tb_n_insns(tb);
  if (!have_guest_base && n > 0) {
    struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, 0);
    void *haddr = qemu_plugin_insn_haddr(insn);
    if (haddr) {
      guest_base = (int64_t)((uintptr_t)haddr - (uintptr_t)qemu_plugin_insn_vaddr(insn));
      __atomic_store_n(&have_guest_base, true, __ATOMIC_RELEASE);
    }
  }
  if (per_vcpu) {
    qemu_plugin_register_vcpu_tb_exec_cb(tb, count_tb, QEMU_PLUGIN_CB_NO_REGS, (void *)(uintptr_t)n);
  } else {
    qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &total_insns, n);
  }
}

static uint64_t vcpu_count(unsigned int vcpu_index) {
  return per_vcpu ? vcpus[vcpu_index].insns : total_insns;
}

/* Copies between this process's memory and a buffer without crashing on a bad address: a guest
 * bug (a wild slot pointer) must cost a logged mismatch, not the emulator. process_vm_readv on
 * ourselves returns EFAULT for unmapped memory; if the host forbids it (EPERM/ENOSYS under some
 * seccomp profiles) fall back to a plain copy. */
static bool copy_checked(void *dst, const void *src, size_t n, bool to_guest) {
  struct iovec local = {to_guest ? (void *)src : dst, n};
  struct iovec remote = {to_guest ? dst : (void *)src, n};
  ssize_t done = to_guest ? process_vm_writev(getpid(), &local, 1, &remote, 1, 0)
                          : process_vm_readv(getpid(), &local, 1, &remote, 1, 0);
  if (done == (ssize_t)n) return true;
  if (done < 0 && (errno == EPERM || errno == ENOSYS)) {
    memcpy(dst, src, n);
    return true;
  }
  return false;
}

/* Writes `value` into the guest's slot if the slot holds SLOT_REQUEST; returns whether it did. */
static bool answer_slot(uint64_t slot_addr, uint64_t value) {
  if (slot_addr == 0 || (slot_addr & 7) != 0 || !__atomic_load_n(&have_guest_base, __ATOMIC_ACQUIRE))
    return false;
  void *host = (void *)(uintptr_t)((int64_t)slot_addr + guest_base);
  uint64_t current;
  if (!copy_checked(&current, host, sizeof current, false) || current != SLOT_REQUEST) return false;
  return copy_checked(host, &value, sizeof value, true);
}

static void on_syscall(qemu_plugin_id_t id, unsigned int vcpu_index, int64_t num, uint64_t op,
                       uint64_t step, uint64_t slot, uint64_t a4, uint64_t a5, uint64_t a6,
                       uint64_t a7, uint64_t a8) {
  (void)id, (void)a4, (void)a5, (void)a6, (void)a7, (void)a8;
  if (num != RVD_MARKER_NR) return;
  if (vcpu_index >= MAX_VCPUS) {
    log_line("# vcpu %u beyond %d: marker ignored\n", vcpu_index, MAX_VCPUS);
    return;
  }
  struct vcpu_state *v = &vcpus[vcpu_index];
  uint64_t now = vcpu_count(vcpu_index);
  if (op == RVD_MARKER_BEGIN) {
    v->begin_mark = now;
    v->begin_step = (uint32_t)step;
    v->in_region = true;
    if (!answer_slot(slot, SLOT_ACK)) n_slot_mismatch++;
  } else if (op == RVD_MARKER_READ) {
    __atomic_add_fetch(&n_reads, 1, __ATOMIC_RELAXED);
    if (!answer_slot(slot, now)) n_slot_mismatch++;
  } else if (op == RVD_MARKER_END) {
    if (!v->in_region || v->begin_step != (uint32_t)step) {
      log_line("# end of step %" PRIu64 " on vcpu %u without its begin: ignored\n", step, vcpu_index);
      return;
    }
    uint64_t insns = now - v->begin_mark;
    v->in_region = false;
    n_regions++;
    if (!answer_slot(slot, insns)) {
      n_slot_mismatch++;
      log_line("# step %" PRIu64 ": guest slot 0x%" PRIx64 " not writable as expected\n", step, slot);
    }
    log_line("%" PRIu64 " %" PRIu64 "\n", step, insns);
  }
}

static void on_vcpu_init(qemu_plugin_id_t id, unsigned int vcpu_index) {
  (void)id;
  unsigned n = __atomic_add_fetch(&n_vcpus, 1, __ATOMIC_RELAXED);
  if (n == 2 && !per_vcpu)
    log_line("# guest started a second thread (vcpu %u): inline counts include all threads; "
             "use count=vcpu for per-thread counts\n", vcpu_index);
}

static void report_at_exit(qemu_plugin_id_t id, void *userdata) {
  (void)id, (void)userdata;
  uint64_t total = total_insns;
  if (per_vcpu) {
    total = 0;
    for (int i = 0; i < MAX_VCPUS; i++) total += vcpus[i].insns;
  }
  log_line("# exit: regions %" PRIu64 ", clock reads %" PRIu64 ", slot mismatches %" PRIu64
           ", total insns %" PRIu64 "\n", n_regions, n_reads, n_slot_mismatch, total);
  if (n_slot_mismatch) {
    char msg[160];
    snprintf(msg, sizeof msg, "rvd insn_count: %" PRIu64 " marker slot(s) could not be answered\n",
             n_slot_mismatch);
    qemu_plugin_outs(msg);
  }
  pthread_mutex_lock(&log_lock);
  if (log_file) fclose(log_file);
  log_file = NULL;
  pthread_mutex_unlock(&log_lock);
}

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info, int argc,
                                           char **argv) {
  if (info->system_emulation) {
    fprintf(stderr, "rvd insn_count: user mode only (system mode has no syscall callbacks; use "
                    "-icount there)\n");
    return -1;
  }
  const char *log_path = NULL;
  for (int i = 0; i < argc; i++) {
    if (strncmp(argv[i], "log=", 4) == 0) {
      log_path = argv[i] + 4;
    } else if (strcmp(argv[i], "count=inline") == 0) {
      per_vcpu = false;
    } else if (strcmp(argv[i], "count=vcpu") == 0) {
      per_vcpu = true;
    } else {
      fprintf(stderr, "rvd insn_count: unknown argument '%s' (log=PATH, count=inline|vcpu)\n", argv[i]);
      return -1;
    }
  }
  if (log_path) {
    log_file = fopen(log_path, "w");
    if (!log_file) {
      fprintf(stderr, "rvd insn_count: cannot open log file '%s'\n", log_path);
      return -1;
    }
    log_line("# rvd insn_count: target %s, count=%s; lines: step insns\n", info->target_name,
             per_vcpu ? "vcpu" : "inline");
  }
  qemu_plugin_register_vcpu_init_cb(id, on_vcpu_init);
  qemu_plugin_register_vcpu_tb_trans_cb(id, on_tb_translate);
  qemu_plugin_register_vcpu_syscall_cb(id, on_syscall);
  qemu_plugin_register_atexit_cb(id, report_at_exit, NULL);
  return 0;
}
