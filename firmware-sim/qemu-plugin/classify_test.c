/*
 * Unit test of classify.h on known encodings, taken from llvm-objdump of the two firmware ELFs
 * (--mcpu=cortex-m55 / cortex-m7), and a few the firmware lacks (sdiv, b, scalar FP) from the
 * Armv7-M Architecture Reference Manual. scripts/firmware.sh compiles and runs it before the plugin.
 * Prints every mismatch and exits 1 on any.
 */
#include <stdio.h>
#include <string.h>

#include "classify.h"

struct known {
    const char *text; /* the disassembly, for the message */
    unsigned hw1, hw2; /* hw2 = 0: a 16-bit instruction */
    enum insn_class cls;
    int mve_memory, extra_words;
};

static const struct known cases[] = {
    {"ldr r2, [r6, #0x28]", 0x6ab2, 0, CLASS_LOAD_STORE, 0, 0},
    {"adds r2, #0x1", 0x3201, 0, CLASS_OTHER, 0, 0},
    {"str r2, [r6, #0x28]", 0x62b2, 0, CLASS_LOAD_STORE, 0, 0},
    {"bne 0x914", 0xd124, 0, CLASS_BRANCH, 0, 0},
    {"movw r0, #0xe010", 0xf24e, 0x0010, CLASS_OTHER, 0, 0},
    {"strb.w r0, [r6, #0x30]", 0xf886, 0x0030, CLASS_LOAD_STORE, 0, 0},
    {"subs.w r12, r12, r11", 0xebbc, 0x0c0b, CLASS_OTHER, 0, 0},
    {"ldm r2!, {r3}", 0xca08, 0, CLASS_LOAD_STORE, 0, 0},
    {"stm r4!, {r0, r1, r2, r3, r5, r6}", 0xc46f, 0, CLASS_LOAD_STORE, 0, 5},
    {"push {r4, r5, r6, r7, lr}", 0xb5f0, 0, CLASS_LOAD_STORE, 0, 4},
    {"pop {r4, r5, r6, r7, pc}", 0xbdf0, 0, CLASS_BRANCH, 0, 4},
    {"push.w {r8, r9, r10, r11}", 0xe92d, 0x0f00, CLASS_LOAD_STORE, 0, 3},
    {"pop.w {r8, r9, r10, r11}", 0xe8bd, 0x0f00, CLASS_LOAD_STORE, 0, 3},
    {"pop.w {r4, r6, r7, lr}", 0xe8bd, 0x40d0, CLASS_LOAD_STORE, 0, 3},
    {"ldm.w r12!, {r0, r2, r3, r4, r6}", 0xe8bc, 0x005d, CLASS_LOAD_STORE, 0, 4},
    {"ldrd r0, r4, [r6, #28]", 0xe9d6, 0x0407, CLASS_LOAD_STORE, 0, 1},
    {"strd r1, r6, [r0, #28]", 0xe9c0, 0x1607, CLASS_LOAD_STORE, 0, 1},
    {"lda r2, [r10]", 0xe8da, 0x2faf, CLASS_LOAD_STORE, 0, 0},
    {"tbb [pc, r1]", 0xe8df, 0xf001, CLASS_BRANCH, 0, 0},
    {"tbh [pc, r1, lsl #1]", 0xe8df, 0xf011, CLASS_BRANCH, 0, 0},
    {"cbz r2, ...", 0xb19a, 0, CLASS_BRANCH, 0, 0},
    {"b .", 0xe7fe, 0, CLASS_BRANCH, 0, 0},
    {"bx r12", 0x4760, 0, CLASS_BRANCH, 0, 0},
    {"udf #0", 0xde00, 0, CLASS_OTHER, 0, 0},
    {"it lo", 0xbf38, 0, CLASS_OTHER, 0, 0},
    {"bl ...", 0xf021, 0xfe66, CLASS_BRANCH, 0, 0},
    {"beq.w ...", 0xf000, 0x813f, CLASS_BRANCH, 0, 0},
    {"b.w ...", 0xf7ff, 0xb8ef, CLASS_BRANCH, 0, 0},
    {"msr primask, r8", 0xf388, 0x8810, CLASS_OTHER, 0, 0},
    {"mrs r8, primask", 0xf3ef, 0x8810, CLASS_OTHER, 0, 0},
    {"isb sy", 0xf3bf, 0x8f6f, CLASS_OTHER, 0, 0},
    {"muls r0, r1, r0", 0x4348, 0, CLASS_MUL, 0, 0},
    {"mla r5, r4, r3, r1", 0xfb04, 0x1503, CLASS_MUL, 0, 0},
    {"smlabb r3, r6, r0, r2", 0xfb16, 0x2300, CLASS_MUL, 0, 0},
    {"smlad r0, r10, r12, r0", 0xfb2a, 0x000c, CLASS_MUL, 0, 0},
    {"umull r1, r5, r1, r5", 0xfba1, 0x1505, CLASS_MUL, 0, 0},
    {"smlal r1, r2, r3, r11", 0xfbc3, 0x120b, CLASS_MUL, 0, 0},
    {"udiv r4, r5, r3", 0xfbb5, 0xf4f3, CLASS_DIV, 0, 0},
    {"sdiv r0, r1, r2", 0xfb91, 0xf0f2, CLASS_DIV, 0, 0},
    {"sxtb16 r12, r3", 0xfa2f, 0xfc83, CLASS_OTHER, 0, 0},
    {"lsll r2, r1, #4", 0xea52, 0x010d, CLASS_OTHER, 0, 0},
    {"le lr, ...", 0xf00f, 0xc0b5, CLASS_LOOP, 0, 0},
    {"letp lr, ...", 0xf01f, 0xc019, CLASS_LOOP, 0, 0},
    {"dls lr, r0", 0xf040, 0xe001, CLASS_LOOP, 0, 0},
    {"dlstp.8 lr, r14", 0xf00e, 0xe001, CLASS_LOOP, 0, 0},
    {"wls lr, r0, ...", 0xf040, 0xc00f, CLASS_LOOP, 0, 0},
    {"vldrb.u8 q4, [r0]", 0xed90, 0x9e00, CLASS_MVE, 1, 0},
    {"vldrb.u8 q2, [r9], #16", 0xecb9, 0x5e10, CLASS_MVE, 1, 0},
    {"vldrb.u32 q6, [r6]", 0xfcb6, 0xcf04, CLASS_MVE, 1, 0},
    {"vstrw.32 q4, [lr, #320]", 0xed8e, 0x9f50, CLASS_MVE, 1, 0},
    {"vmlava.s8 r0, q2, q2", 0xeef0, 0x0f24, CLASS_MVE, 0, 0},
    {"vmlalva.s16 r0, r1, q0, q0", 0xee80, 0x0e20, CLASS_MVE, 0, 0},
    {"vadd.i32 q3, q4, q3", 0xef28, 0x6846, CLASS_MVE, 0, 0},
    {"vmov.i8 q7, #0xff", 0xff87, 0xe05f, CLASS_MVE, 0, 0},
    {"vdup.32 q6, r12", 0xeeac, 0xcb10, CLASS_MVE, 0, 0},
    {"vpst", 0xfe71, 0x0f4d, CLASS_MVE, 0, 0},
    {"vpush {d8-d15}", 0xed2d, 0x8b10, CLASS_LOAD_STORE, 0, 15},
    {"vpop {d8-d15}", 0xecbd, 0x8b10, CLASS_LOAD_STORE, 0, 15},
    {"vldr d0, [r0]", 0xed90, 0x0b00, CLASS_LOAD_STORE, 0, 1},
    {"vmov r0, s0", 0xee10, 0x0a10, CLASS_FP, 0, 0},
    {"vadd.f32 s0, s0, s1", 0xee30, 0x0a20, CLASS_FP, 0, 0},
};

/* A 16-bit instruction handed over with the next halfword (QEMU does so at a page end). */
static int check_width(void)
{
    const uint8_t add_sp_then_pop_w[4] = {0x07, 0xb0, 0xbd, 0xe8}; /* add sp, #28; pop.w ... */
    struct insn_info got = classify_thumb(add_sp_then_pop_w, 4);
    if (got.cls != CLASS_OTHER) {
        printf("add sp, #28 given 4 bytes: found %s, expected other\n", class_names[got.cls]);
        return 1;
    }
    return 0;
}

static int check_counts(void)
{
    /* vldrb, vmlava, vldrb, vmlava: each after the first overlaps its predecessor (other unit);
     * then add, add (an ALU pair), ldr, smlabb (a load/store + MAC pair), bne. */
    static const unsigned block[][2] = {{0xed90, 0x9e00}, {0xeef0, 0x0f24}, {0xed90, 0x9e00},
                                        {0xeef0, 0x0f24}, {0x3201, 0},      {0x3201, 0},
                                        {0x6ab2, 0},      {0xfb16, 0x2300}, {0xd124, 0}};
    uint64_t counts[N_COUNTERS] = {0};
    struct insn_info prev = {CLASS_OTHER, 0, 0};
    int prev_paired = 0;
    for (size_t i = 0; i < sizeof block / sizeof block[0]; i++) {
        uint8_t b[4] = {block[i][0] & 0xFF, block[i][0] >> 8, block[i][1] & 0xFF, block[i][1] >> 8};
        struct insn_info cur = classify_thumb(b, block[i][1] ? 4 : 2);
        count_insn(counts, i ? &prev : NULL, &cur, &prev_paired);
        prev = cur;
    }
    const uint64_t want[N_COUNTERS] = {[CLASS_MVE] = 4,        [CLASS_OTHER] = 2,    [CLASS_LOAD_STORE] = 1,
                                       [CLASS_MUL] = 1,        [CLASS_BRANCH] = 1,   [ADJ_MVE_OVERLAP] = 3,
                                       [ADJ_DUAL_PAIR] = 2};
    int bad = 0;
    for (int k = 0; k < N_COUNTERS; k++) {
        if (counts[k] != want[k]) {
            const char *name = k < N_CLASSES ? class_names[k] : adjustment_names[k - N_CLASSES];
            printf("block counter %s: found %llu, expected %llu\n", name, (unsigned long long)counts[k],
                   (unsigned long long)want[k]);
            bad = 1;
        }
    }
    return bad;
}

int main(void)
{
    int bad = 0;
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        const struct known *c = &cases[i];
        uint8_t b[4] = {c->hw1 & 0xFF, c->hw1 >> 8, c->hw2 & 0xFF, c->hw2 >> 8};
        struct insn_info got = classify_thumb(b, c->hw2 ? 4 : 2);
        if (got.cls != c->cls || got.mve_memory != c->mve_memory || got.extra_words != c->extra_words) {
            printf("%s (%04x %04x): found %s memory=%d extra=%d, expected %s memory=%d extra=%d\n", c->text,
                   c->hw1, c->hw2, class_names[got.cls], got.mve_memory, got.extra_words, class_names[c->cls],
                   c->mve_memory, c->extra_words);
            bad = 1;
        }
    }
    bad |= check_width();
    bad |= check_counts();
    printf("classify_test: %zu encodings and one block, %s\n", sizeof cases / sizeof cases[0],
           bad ? "FAILED" : "ok");
    return bad;
}
