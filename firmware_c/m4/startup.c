/*
 * startup.c - reset handler and vector table for the QEMU mps2-an386 board.
 *
 * Copies .data, zeroes .bss, enables the FPU (CPACR: full access to CP10 and
 * CP11) before any float instruction runs, calls main() and ends the QEMU run
 * with main's return value as exit status (semihosting SYS_EXIT_EXTENDED).
 * Any fault also ends the run, with exit status 99.
 */
#include <stdint.h>

#include "semihost.h"

int main(void);

extern uint32_t _data_load[], _data_start[], _data_end[], _bss_start[], _bss_end[];
extern uint32_t _stack_top[];

#define CPACR (*(volatile uint32_t *)0xE000ED88u)

/** Reset entry: set up memory and the FPU, run main, exit with its status. */
__attribute__((noreturn, used)) void reset_handler(void)
{
    uint32_t *src = _data_load, *dst = _data_start;
    while (dst < _data_end) {
        *dst++ = *src++;
    }
    for (dst = _bss_start; dst < _bss_end; dst++) {
        *dst = 0u;
    }
    CPACR |= (0xFu << 20); /* CP10, CP11: full access */
    __asm__ volatile("dsb\n\tisb" ::: "memory");
    semihost_exit(main());
}

/** Faults and unexpected interrupts: exit status 99. */
__attribute__((noreturn)) static void fault_handler(void)
{
    semihost_write0("fault\n");
    semihost_exit(99);
}

/** Cortex-M vector table: initial stack pointer, reset and the core exceptions. */
__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))_stack_top,
    reset_handler,
    fault_handler, /* NMI */
    fault_handler, /* HardFault */
    fault_handler, /* MemManage */
    fault_handler, /* BusFault */
    fault_handler, /* UsageFault */
    0, 0, 0, 0,
    fault_handler, /* SVCall */
    fault_handler, /* DebugMonitor */
    0,
    fault_handler, /* PendSV */
    fault_handler, /* SysTick */
};
