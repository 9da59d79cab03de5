/* CMSIS-NN on the engine's kernel shapes, counted by the project's QEMU instruction-count plugin
 * between `bino_mark_cmsis_*` markers, the way the kernel test firmware's bench counts the
 * project's kernels (firmware-sim/src/bin/kernel-tests.rs): the same calls x shapes, random int8
 * data, per-channel requantisation and the int8 store included (`arm_nn_mat_mult_nt_t_s8`), and
 * `arm_softmax_s8` on 960-long rows. Built and run only by `scripts/firmware.sh --cmsis-nn DIR`;
 * CMSIS-NN itself is never part of the repository. */
#include <stdint.h>

#include "arm_nnfunctions.h"
#include "arm_nnsupportfunctions.h"

void bench_print(const char *text);

/* The stage the plugin attributes work to: distinct stores keep the markers distinct functions. */
static volatile uint32_t current;
#define MARKER(name, id)                                                                          \
    __attribute__((noinline, used)) void bino_mark_cmsis_##name(void) { current = (id); }
MARKER(qkv, 1)
MARKER(mlp_up, 2)
MARKER(mlp_down, 3)
MARKER(scores, 4)
MARKER(pv, 5)
MARKER(softmax, 6)
__attribute__((noinline, used)) void bino_mark_end(void) { current = 0xFFFF; }

#define MAX_LHS (8 * 960)
#define MAX_RHS (960 * 128)
#define MAX_N 960
static int8_t lhs[MAX_LHS], rhs[MAX_RHS], dst[8 * MAX_N], soft_in[16 * 960], soft_out[16 * 960];
static int32_t bias[MAX_N], mult[MAX_N], shift[MAX_N];

static uint32_t state = 0x12345678u;
static int8_t random_i8(void)
{
    state = state * 1664525u + 1013904223u;
    return (int8_t)(state >> 24);
}

static void fill(int8_t *x, int n)
{
    for (int i = 0; i < n; i++) {
        x[i] = random_i8();
    }
}

static int failed;

/* A line of text and decimal numbers (no printf: newlib's would pull in the heap). */
static char line[160];
static int line_len;
static void put_text(const char *t)
{
    while (*t && line_len < (int)sizeof line - 1) {
        line[line_len++] = *t++;
    }
}
static void put_number(long v)
{
    char digits[24];
    int n = 0;
    if (v < 0) {
        put_text("-");
        v = -v;
    }
    do {
        digits[n++] = (char)('0' + v % 10);
        v /= 10;
    } while (v && n < (int)sizeof digits);
    while (n && line_len < (int)sizeof line - 1) {
        line[line_len++] = digits[--n];
    }
}
static void put_end(void)
{
    line[line_len] = 0;
    bench_print(line);
    line_len = 0;
}

/* `calls` times an m x k by (n x k)^T product with the requantisation, as the engine calls it. */
static void gemm(const char *name, void (*mark)(void), int calls, int m, int k, int n)
{
    mark();
    for (int c = 0; c < calls; c++) {
        if (arm_nn_mat_mult_nt_t_s8(lhs, rhs, bias, dst, mult, shift, m, n, k, 0, 0, -128, 127, n, k) !=
            ARM_CMSIS_NN_SUCCESS) {
            failed = 1;
        }
    }
    bino_mark_end();
    put_text("cmsis-bench kernel=");
    put_text(name);
    put_text(" m=");
    put_number(m);
    put_text(" k=");
    put_number(k);
    put_text(" n=");
    put_number(n);
    put_text(" calls=");
    put_number(calls);
    put_text(" macs=");
    put_number((long)calls * m * k * n);
    put_text("\n");
    put_end();
}

int main(void)
{
    fill(lhs, MAX_LHS);
    fill(rhs, MAX_RHS);
    fill(soft_in, 16 * 960);
    for (int c = 0; c < MAX_N; c++) {
        bias[c] = random_i8() * 64;
        mult[c] = 1073741824 + (int32_t)(uint8_t)random_i8() * 4194304; /* 0.5 .. 1 in Q31 */
        shift[c] = -9 - (c % 4);                                        /* right shifts 9-12 */
    }
    gemm("qkv", bino_mark_cmsis_qkv, 120, 8, 128, 384);
    gemm("mlp_up", bino_mark_cmsis_mlp_up, 120, 8, 128, 480);
    gemm("mlp_down", bino_mark_cmsis_mlp_down, 120, 8, 480, 128);
    gemm("scores", bino_mark_cmsis_scores, 240, 4, 32, 960);
    gemm("pv", bino_mark_cmsis_pv, 240, 4, 960, 32);
    /* TFLite's softmax parameters from CMSIS-NN's own test data (input scale 1/16, beta 1). */
    bino_mark_cmsis_softmax();
    arm_softmax_s8(soft_in, 16, 960, 1077952640, 19, -3968, soft_out);
    bino_mark_end();
    bench_print("cmsis-bench-rows kernel=softmax rows=16 n=960 elements=15360\n");
    bench_print(failed ? "cmsis-bench result=fail\n" : "cmsis-bench result=pass\n");
    return failed;
}
