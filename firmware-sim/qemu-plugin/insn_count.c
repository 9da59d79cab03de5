/*
 * Executed-instruction counts per firmware stage, for QEMU 7.2 system emulation (one vCPU).
 *
 *   qemu-system-arm ... -plugin libinsn_count.so,out=FILE,mark=NAME:ADDR,...[,profile=FILE][,classes=FILE]
 *
 * Every executed translation block adds its instruction count to one running total (an inline
 * add, no callback). A callback sits only on each marker address (a `bino_mark_<stage>`
 * function's first instruction, taken from the ELF with llvm-nm): when a marker runs, the
 * instructions since the previous marker go to the stage that was current, and the marker's
 * stage becomes current. Instructions before the first marker go to "startup". At exit the
 * plugin writes one line per stage to FILE: name, instructions, times entered; then "total".
 *
 * A block's count is added when the block starts, so a marker function's own few instructions
 * count towards the stage it opens. These are executed instructions, not cycles.
 *
 * With profile=FILE the plugin also counts executions of every translation block (one more
 * inline add per block) and writes "start address, instructions in the block, executions" per
 * block to FILE, for a per-function profile (scripts/firmware.sh maps addresses to symbols).
 *
 * With classes=FILE it also classifies every instruction once, at translation, from its bytes
 * (classify.h: MVE, FP, multiply, divide, load/store, branch, loop, other, and the adjustments the
 * cycle model of CYCLES.md prices), adds each block's per-class totals inline the same way, and
 * writes one line per stage with its counts per class to FILE; a stage's classes add up to its
 * instructions. The instruction counts themselves are the same with or without it.
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "classify.h"
#include "qemu-plugin-v1.h"

QEMU_PLUGIN_EXPORT int qemu_plugin_version = 1;

#define MAX_MARKS 64 /* stage markers, the E7 frame's included, and "end" */

struct mark {
    char name[64];
    uint64_t addr;
    uint64_t insns;
    uint64_t entered;
    uint64_t classes[N_COUNTERS]; /* per class and adjustment, with classes=FILE */
};

static struct mark marks[MAX_MARKS + 1]; /* marks[0] is "startup" */
static int n_marks = 1;
static int current;
static uint64_t total;      /* instructions executed so far (inline adds) */
static uint64_t last_total; /* total at the last marker */
static char out_path[4096];
static char profile_path[4096];
static char classes_path[4096];
static uint64_t class_total[N_COUNTERS]; /* per class so far (inline adds), with classes=FILE */
static uint64_t class_last[N_COUNTERS];  /* class_total at the last marker */

/* Per-block execution counters for profile=FILE, in fixed chunks so their addresses (baked into
 * the translated code) never move. */
struct block {
    uint64_t vaddr;
    uint64_t n_insns;
    uint64_t executed;
};
#define CHUNK 4096
static struct block *chunks[4096];
static size_t n_blocks;

static struct block *new_block(void)
{
    size_t c = n_blocks / CHUNK;
    if (c >= sizeof chunks / sizeof chunks[0]) {
        return NULL;
    }
    if (!chunks[c]) {
        chunks[c] = calloc(CHUNK, sizeof(struct block));
        if (!chunks[c]) {
            return NULL;
        }
    }
    return &chunks[c][n_blocks++ % CHUNK];
}

static void close_interval(void)
{
    marks[current].insns += total - last_total;
    last_total = total;
    for (int k = 0; k < N_COUNTERS; k++) {
        marks[current].classes[k] += class_total[k] - class_last[k];
        class_last[k] = class_total[k];
    }
}

static void on_mark(unsigned int vcpu_index, void *userdata)
{
    (void)vcpu_index;
    close_interval();
    current = (int)(intptr_t)userdata;
    marks[current].entered++;
}

/* Classifies the block's instructions and adds its per-class totals to class_total each time it
 * runs: one inline add per class present, no callback. */
static void count_classes(struct qemu_plugin_tb *tb, size_t n)
{
    uint64_t counts[N_COUNTERS] = {0};
    struct insn_info prev = {CLASS_OTHER, 0, 0};
    int prev_paired = 0;
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        struct insn_info cur = classify_thumb(qemu_plugin_insn_data(insn), qemu_plugin_insn_size(insn));
        count_insn(counts, i > 0 ? &prev : NULL, &cur, &prev_paired);
        prev = cur;
    }
    for (int k = 0; k < N_COUNTERS; k++) {
        if (counts[k]) {
            qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &class_total[k], counts[k]);
        }
    }
}

static void write_classes(void)
{
    FILE *f = fopen(classes_path, "w");
    if (!f) {
        perror(classes_path);
        return;
    }
    fprintf(f, "# stage");
    for (int k = 0; k < N_COUNTERS; k++) {
        fprintf(f, "\t%s", k < N_CLASSES ? class_names[k] : adjustment_names[k - N_CLASSES]);
    }
    fprintf(f, "\n");
    for (int m = 0; m < n_marks; m++) {
        fprintf(f, "%s", marks[m].name);
        for (int k = 0; k < N_COUNTERS; k++) {
            fprintf(f, "\t%" PRIu64, marks[m].classes[k]);
        }
        fprintf(f, "\n");
    }
    fprintf(f, "total");
    for (int k = 0; k < N_COUNTERS; k++) {
        fprintf(f, "\t%" PRIu64, class_total[k]);
    }
    fprintf(f, "\n");
    fclose(f);
}

static void on_tb_trans(qemu_plugin_id_t id, struct qemu_plugin_tb *tb)
{
    (void)id;
    size_t n = qemu_plugin_tb_n_insns(tb);
    qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &total, n);
    if (profile_path[0] && n > 0) {
        struct block *b = new_block();
        if (b) {
            b->vaddr = qemu_plugin_insn_vaddr(qemu_plugin_tb_get_insn(tb, 0));
            b->n_insns = n;
            qemu_plugin_register_vcpu_tb_exec_inline(tb, QEMU_PLUGIN_INLINE_ADD_U64, &b->executed, 1);
        }
    }
    if (classes_path[0]) {
        count_classes(tb, n);
    }
    for (size_t i = 0; i < n; i++) {
        struct qemu_plugin_insn *insn = qemu_plugin_tb_get_insn(tb, i);
        uint64_t vaddr = qemu_plugin_insn_vaddr(insn);
        for (int m = 1; m < n_marks; m++) {
            if (marks[m].addr == vaddr) {
                qemu_plugin_register_vcpu_insn_exec_cb(insn, on_mark, QEMU_PLUGIN_CB_NO_REGS,
                                                       (void *)(intptr_t)m);
            }
        }
    }
}

static void on_plugin_exit(qemu_plugin_id_t id, void *userdata)
{
    (void)id;
    (void)userdata;
    close_interval();
    FILE *f = out_path[0] ? fopen(out_path, "w") : stderr;
    if (!f) {
        perror(out_path);
        return;
    }
    fprintf(f, "# stage\tinstructions\tentered\n");
    for (int m = 0; m < n_marks; m++) {
        fprintf(f, "%s\t%" PRIu64 "\t%" PRIu64 "\n", marks[m].name, marks[m].insns, marks[m].entered);
    }
    fprintf(f, "total\t%" PRIu64 "\t1\n", total);
    if (f != stderr) {
        fclose(f);
    }
    if (classes_path[0]) {
        write_classes();
    }
    if (profile_path[0]) {
        FILE *p = fopen(profile_path, "w");
        if (!p) {
            perror(profile_path);
            return;
        }
        fprintf(p, "# block_vaddr\tinstructions_per_execution\texecutions\n");
        for (size_t i = 0; i < n_blocks; i++) {
            const struct block *b = &chunks[i / CHUNK][i % CHUNK];
            if (b->executed) {
                fprintf(p, "0x%" PRIx64 "\t%" PRIu64 "\t%" PRIu64 "\n", b->vaddr, b->n_insns, b->executed);
            }
        }
        fclose(p);
    }
}

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info, int argc, char **argv)
{
    (void)info;
    strcpy(marks[0].name, "startup");
    marks[0].entered = 1;
    for (int i = 0; i < argc; i++) {
        const char *arg = argv[i];
        if (strncmp(arg, "out=", 4) == 0) {
            snprintf(out_path, sizeof out_path, "%s", arg + 4);
        } else if (strncmp(arg, "profile=", 8) == 0) {
            snprintf(profile_path, sizeof profile_path, "%s", arg + 8);
        } else if (strncmp(arg, "classes=", 8) == 0) {
            snprintf(classes_path, sizeof classes_path, "%s", arg + 8);
        } else if (strncmp(arg, "mark=", 5) == 0) {
            const char *colon = strrchr(arg + 5, ':');
            if (!colon || n_marks > MAX_MARKS || (size_t)(colon - (arg + 5)) >= sizeof marks[0].name) {
                fprintf(stderr, "insn_count: bad argument %s (want mark=NAME:ADDR)\n", arg);
                return -1;
            }
            struct mark *m = &marks[n_marks++];
            memcpy(m->name, arg + 5, (size_t)(colon - (arg + 5)));
            m->addr = strtoull(colon + 1, NULL, 0);
        } else {
            fprintf(stderr, "insn_count: unknown argument %s\n", arg);
            return -1;
        }
    }
    qemu_plugin_register_vcpu_tb_trans_cb(id, on_tb_trans);
    qemu_plugin_register_atexit_cb(id, on_plugin_exit, NULL);
    return 0;
}
