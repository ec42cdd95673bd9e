/*
 * device_main.c - the device firmware: the link on UART0, a status heartbeat every second.
 *
 * The core sleeps (WFI) until a byte arrives or SysTick wraps: interrupts are masked
 * (PRIMASK), so they only wake it and the loop does the work; an idle device costs no CPU.
 * SysTick is looked at after every byte too: a device working through a backlog of frames (a
 * slow core, or a host that sent many at once) still sends its heartbeat every second, so the
 * host does not take it for hung.
 *
 * Run under QEMU with UART0 on a socket (docs/kernel.md, "Device firmware"):
 *     qemu-system-arm -M mps2-an386 -nographic -monitor none -kernel device.elf \
 *         -chardev socket,id=u0,host=127.0.0.1,port=PORT,server=on,wait=off -serial chardev:u0
 */
#include <stdint.h>

#include "device.h"
#include "uart.h"

#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)
#define SYST_COUNTFLAG (1u << 16)
#define ICSR (*(volatile uint32_t *)0xE000ED04u)
#define ICSR_PENDSTCLR (1u << 25)
#define CPU_HZ 25000000u /* mps2-an386 core clock */
#define TICKS_PER_HEARTBEAT 10u /* SysTick wraps every 100 ms */

static Device device; /* the one device of this board (static: off the stack) */

/** A heartbeat every TICKS_PER_HEARTBEAT SysTick wraps (reading the flag clears it). */
static void beat(uint32_t *ticks)
{
    if ((SYST_CSR & SYST_COUNTFLAG) != 0u) {
        ICSR = ICSR_PENDSTCLR;
        if (++*ticks == TICKS_PER_HEARTBEAT) {
            *ticks = 0u;
            device_heartbeat(&device);
        }
    }
}

int main(void)
{
    uint32_t ticks = 0u;
    uart_init();
    SYST_RVR = CPU_HZ / 10u - 1u;
    SYST_CVR = 0u;
    __asm__ volatile("cpsid i" ::: "memory"); /* interrupts wake WFI, handlers never run */
    SYST_CSR = 0x7u; /* enabled, core clock, its exception pends (a wake-up) */
    uart_wake_on_rx();
    device_init(&device, uart_write);
    for (;;) {
        int byte;
        __asm__ volatile("wfi" ::: "memory");
        uart_clear_wake();
        while ((byte = uart_poll()) >= 0) {
            device_byte(&device, (uint8_t)byte);
            beat(&ticks);
        }
        beat(&ticks);
    }
}
