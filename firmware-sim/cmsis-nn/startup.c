/* Minimal bare-metal start for the CMSIS-NN bench on QEMU's mps3-an547 (Cortex-M55) and
 * mps2-an500 (Cortex-M7): vector table, .data/.bss set-up, FPU (and MVE) enabled, semihosting
 * output and exit. Not part of the product: only scripts/firmware.sh --cmsis-nn builds it. */
#include <stdint.h>

extern uint32_t __stack_top, __data_load, __data_start, __data_end, __bss_start, __bss_end;
int main(void);

/* Semihosting call (`bkpt 0xab`): QEMU runs with -semihosting-config enable=on. */
static int semihost(int op, const void *arg)
{
    register int r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

void bench_print(const char *text) { semihost(0x04, text); /* SYS_WRITE0 */ }

__attribute__((noreturn)) void bench_exit(int failed)
{
    /* SYS_EXIT: ADP_Stopped_ApplicationExit (QEMU exits 0) or RunTimeErrorUnknown (exit 1). */
    semihost(0x18, (const void *)(uintptr_t)(failed ? 0x20024 : 0x20026));
    for (;;) {
    }
}

__attribute__((noreturn)) void reset_handler(void)
{
    uint32_t *src = &__data_load;
    for (uint32_t *dst = &__data_start; dst < &__data_end;) {
        *dst++ = *src++;
    }
    for (uint32_t *dst = &__bss_start; dst < &__bss_end;) {
        *dst++ = 0;
    }
    /* CPACR: full access to CP10 and CP11 (the FPU, and MVE on the Cortex-M55). */
    *(volatile uint32_t *)0xE000ED88 |= 0xFu << 20;
    __asm__ volatile("dsb\n\tisb" ::: "memory");
    bench_exit(main());
}

__attribute__((noreturn)) static void fault_handler(void)
{
    bench_print("cmsis-bench fault\n");
    bench_exit(1);
}

__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))(&__stack_top), reset_handler, fault_handler, fault_handler,
    fault_handler, fault_handler, fault_handler, 0, 0, 0, 0, fault_handler, fault_handler, 0,
    fault_handler, fault_handler,
};
