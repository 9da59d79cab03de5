/*
 * Instruction classes for the cycle model of `bino budget` (see CYCLES.md): a decoder of the
 * Thumb-2 encoding space (Armv7-M with the DSP extension, Armv8.1-M with MVE and low-overhead
 * loops) down to the classes the model prices, from the instruction's bytes alone. Header-only so
 * that insn_count.c and classify_test.c share it; no QEMU dependency.
 *
 * Besides each instruction's class it counts, per translation block, three adjustments the model
 * prices separately: MVE instructions that overlap their predecessor (a vector load/store next to
 * a vector compute instruction: the Cortex-M55 runs their beats in parallel), scalar pairs the
 * Cortex-M7 could dual-issue by pipeline (dependencies between the two are not decoded), and
 * 32-bit words moved beyond the first by LDM/STM/PUSH/POP/LDRD/STRD/VLDM/VSTM/VPUSH/VPOP.
 */
#ifndef BINO_CLASSIFY_H
#define BINO_CLASSIFY_H

#include <stddef.h>
#include <stdint.h>

enum insn_class {
    CLASS_MVE,        /* Helium (MVE) vector instruction, incl. vector loads/stores and VDUP */
    CLASS_FP,         /* scalar FP / register transfers in the FP coprocessor space (cp10, cp11) */
    CLASS_MUL,        /* MUL, MLA, MLS, SMLA*, SMUL*, SMLAD, SMMLA, UMULL, SMLAL, ... */
    CLASS_DIV,        /* SDIV, UDIV */
    CLASS_LOAD_STORE, /* LDR/STR of every size, LDRD/STRD, LDM/STM, PUSH/POP, LDREX, VLDR/VSTR, VPUSH */
    CLASS_BRANCH,     /* B, BL, BX, BLX, CBZ, TBB/TBH, POP {..pc}, LDM {..pc}, writes of pc */
    CLASS_LOOP,       /* Armv8.1-M low-overhead loops: LE, LETP, DLS, WLS, DLSTP, WLSTP */
    CLASS_OTHER,      /* everything else: ALU, shifts, moves, IT, compares, hints, MSR/MRS */
    N_CLASSES
};

/* Column names, in enum order, then the three adjustments. */
static const char *const class_names[N_CLASSES] = {
    "mve", "fp", "mul", "div", "load_store", "branch", "loop", "other",
};
enum { ADJ_MVE_OVERLAP = N_CLASSES, ADJ_DUAL_PAIR, ADJ_EXTRA_WORDS, N_COUNTERS };
static const char *const adjustment_names[N_COUNTERS - N_CLASSES] = {
    "mve_overlap", "dual_issue_pair", "extra_words",
};

struct insn_info {
    enum insn_class cls;
    int mve_memory;  /* an MVE load or store (the M55's load/store unit, not its ALU/MAC) */
    int extra_words; /* 32-bit words transferred beyond the first */
};

static int popcount16(unsigned v)
{
    int n = 0;
    for (v &= 0xFFFF; v; v &= v - 1) {
        n++;
    }
    return n;
}

static struct insn_info info(enum insn_class cls, int mve_memory, int extra_words)
{
    struct insn_info i = {cls, mve_memory, extra_words > 0 ? extra_words : 0};
    return i;
}

static struct insn_info classify16(unsigned hw)
{
    if ((hw & 0xFFC0) == 0x4340) { /* MULS */
        return info(CLASS_MUL, 0, 0);
    }
    if ((hw & 0xFF00) == 0x4700 || (hw & 0xFF87) == 0x4687 || (hw & 0xFF87) == 0x4487) {
        return info(CLASS_BRANCH, 0, 0); /* BX, BLX, MOV pc, ADD pc */
    }
    if ((hw & 0xF800) == 0x4800 || (hw & 0xF000) == 0x5000 || (hw & 0xE000) == 0x6000 ||
        (hw & 0xE000) == 0x8000) { /* LDR literal, register offset, immediate, SP-relative */
        return info(CLASS_LOAD_STORE, 0, 0);
    }
    if ((hw & 0xF000) == 0xC000) { /* LDM/STM */
        return info(CLASS_LOAD_STORE, 0, popcount16(hw & 0xFF) - 1);
    }
    if ((hw & 0xFE00) == 0xB400) { /* PUSH */
        return info(CLASS_LOAD_STORE, 0, popcount16(hw & 0x1FF) - 1);
    }
    if ((hw & 0xFE00) == 0xBC00) { /* POP, a return when it loads pc */
        return info((hw & 0x100) ? CLASS_BRANCH : CLASS_LOAD_STORE, 0, popcount16(hw & 0x1FF) - 1);
    }
    if ((hw & 0xF500) == 0xB100 || (hw & 0xF800) == 0xE000) { /* CBZ/CBNZ, B */
        return info(CLASS_BRANCH, 0, 0);
    }
    if ((hw & 0xF000) == 0xD000) { /* B<cond>; UDF and SVC where cond is 111x */
        return info((hw & 0x0E00) == 0x0E00 ? CLASS_OTHER : CLASS_BRANCH, 0, 0);
    }
    return info(CLASS_OTHER, 0, 0);
}

static struct insn_info classify_coprocessor(unsigned hw1, unsigned hw2)
{
    unsigned cp = (hw2 >> 8) & 0xF;
    /* Load/store space (111x 110x) except its register-pair transfers (P = U = W = 0). */
    int memory = (hw1 & 0xEE00) == 0xEC00 && (hw1 & 0xFFA0) != 0xEC00;
    int vdup = (hw1 & 0xFF90) == 0xEE80 && (hw2 & 0x0F50) == 0x0B10;
    /* MVE: the 111x 1111 space, coprocessor numbers 14 and 15, and VDUP (which shares cp11). */
    if ((hw1 & 0xEF00) == 0xEF00 || (cp & 0xE) == 0xE || vdup) {
        return info(CLASS_MVE, memory, 0);
    }
    if (memory) {
        int words;
        if ((hw1 & 0x0120) == 0x0100) { /* VLDR/VSTR (P = 1, W = 0): one S or D register */
            words = cp == 0xB ? 2 : 1;
        } else { /* VLDM/VSTM/VPUSH/VPOP: imm8 words */
            words = (int)(hw2 & 0xFF);
        }
        return info(CLASS_LOAD_STORE, 0, words - 1);
    }
    return info(CLASS_FP, 0, 0);
}

static struct insn_info classify32(unsigned hw1, unsigned hw2)
{
    if ((hw1 & 0xEC00) == 0xEC00) {
        return classify_coprocessor(hw1, hw2);
    }
    switch ((hw1 >> 11) & 3) {
    case 1:
        if ((hw1 & 0xFE40) == 0xE800) { /* LDM/STM (PUSH.W/POP.W); a return when it loads pc */
            int loads_pc = (hw1 & 0x0010) && (hw2 & 0x8000);
            return info(loads_pc ? CLASS_BRANCH : CLASS_LOAD_STORE, 0, popcount16(hw2) - 1);
        }
        if ((hw1 & 0xFE40) == 0xE840) { /* dual, exclusive, acquire/release, table branch */
            if ((hw1 & 0xFFF0) == 0xE8D0 && (hw2 & 0xFFE0) == 0xF000) {
                return info(CLASS_BRANCH, 0, 0); /* TBB/TBH */
            }
            return info(CLASS_LOAD_STORE, 0, (hw1 & 0x0120) ? 1 : 0); /* LDRD/STRD: P or W set */
        }
        return info(CLASS_OTHER, 0, 0); /* data processing (shifted register), MVE scalar shifts */
    case 2:
        if (!(hw2 & 0x8000)) {
            return info(CLASS_OTHER, 0, 0); /* data processing (immediate) */
        }
        if ((hw2 & 0xD000) == 0xC000) {
            return info(CLASS_LOOP, 0, 0); /* LE/LETP/DLS/WLS (BLX immediate on A-profile only) */
        }
        if ((hw2 & 0x5000) == 0 && (hw1 & 0x0380) == 0x0380) {
            return info(CLASS_OTHER, 0, 0); /* MSR, MRS, hints, barriers */
        }
        return info(CLASS_BRANCH, 0, 0); /* B<cond>.W, B.W, BL */
    default: /* 3 */
        if ((hw1 & 0xFE00) == 0xF800) { /* load/store single, preload; LDR pc is a branch */
            int loads_pc = (hw1 & 0x0070) == 0x0050 && (hw2 >> 12) == 0xF;
            return info(loads_pc ? CLASS_BRANCH : CLASS_LOAD_STORE, 0, 0);
        }
        if ((hw1 & 0xFF80) == 0xFB00) {
            return info(CLASS_MUL, 0, 0); /* multiply, multiply-accumulate, dual 16-bit MAC */
        }
        if ((hw1 & 0xFF80) == 0xFB80) { /* long multiply (accumulate), divide */
            int divide = (hw1 & 0xFFD0) == 0xFB90 && (hw2 & 0x00F0) == 0x00F0;
            return info(divide ? CLASS_DIV : CLASS_MUL, 0, 0);
        }
        return info(CLASS_OTHER, 0, 0); /* data processing (register), parallel add/sub, extend */
    }
}

/* The class of the Thumb instruction in `bytes` (little-endian halfwords, `size` bytes). Its
 * width comes from its first halfword, not from `size`: QEMU 7.2 hands a 16-bit instruction
 * that ends a (1 KiB) page over with 4 bytes, the translator having peeked at the next one. */
static struct insn_info classify_thumb(const uint8_t *bytes, size_t size)
{
    unsigned hw1 = (unsigned)bytes[0] | (unsigned)bytes[1] << 8;
    if (size < 4 || (hw1 >> 11) < 0x1D) {
        return classify16(hw1);
    }
    return classify32(hw1, (unsigned)bytes[2] | (unsigned)bytes[3] << 8);
}

/* The Cortex-M7 pipeline an instruction issues to, for the dual-issue pairing. */
enum m7_pipe { PIPE_ALU, PIPE_MAC, PIPE_LOAD_STORE, PIPE_BRANCH, PIPE_FP, PIPE_NONE };

static enum m7_pipe m7_pipe(enum insn_class cls)
{
    switch (cls) {
    case CLASS_OTHER:
        return PIPE_ALU;
    case CLASS_MUL:
        return PIPE_MAC;
    case CLASS_LOAD_STORE:
        return PIPE_LOAD_STORE;
    case CLASS_BRANCH:
    case CLASS_LOOP:
        return PIPE_BRANCH;
    case CLASS_FP:
        return PIPE_FP;
    default:
        return PIPE_NONE; /* DIV (iterative, issues alone), MVE (not on the M7) */
    }
}

/* Whether `b` may issue in the same cycle as the instruction before it, `a`: two pipelines, or
 * both on the M7's two ALUs; a branch ends its issue group. */
static int m7_pairs(enum insn_class a, enum insn_class b)
{
    enum m7_pipe pa = m7_pipe(a), pb = m7_pipe(b);
    if (pa == PIPE_NONE || pb == PIPE_NONE || pa == PIPE_BRANCH) {
        return 0;
    }
    return pa != pb || pa == PIPE_ALU;
}

/* Adds the counters of one instruction, `cur`, that follows `prev` (NULL for the first of a
 * block) to `counts` (N_COUNTERS entries). `*prev_paired` says whether `prev` already pairs with
 * the one before it; updated for the next call. */
static void count_insn(uint64_t *counts, const struct insn_info *prev, const struct insn_info *cur,
                       int *prev_paired)
{
    counts[cur->cls]++;
    counts[ADJ_EXTRA_WORDS] += (uint64_t)cur->extra_words;
    int paired = 0;
    if (prev) {
        if (prev->cls == CLASS_MVE && cur->cls == CLASS_MVE && prev->mve_memory != cur->mve_memory) {
            counts[ADJ_MVE_OVERLAP]++;
        }
        if (!*prev_paired && m7_pairs(prev->cls, cur->cls)) {
            counts[ADJ_DUAL_PAIR]++;
            paired = 1;
        }
    }
    *prev_paired = paired;
}

#endif
