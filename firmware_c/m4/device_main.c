/*
 * device_main.c - the device firmware: the link on UART0, a status heartbeat every second.
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
#define CPU_HZ 25000000u /* mps2-an386 core clock */
#define TICKS_PER_HEARTBEAT 10u /* SysTick wraps every 100 ms */

int main(void)
{
    uint32_t ticks = 0u;
    uart_init();
    SYST_RVR = CPU_HZ / 10u - 1u;
    SYST_CVR = 0u;
    SYST_CSR = 0x5u; /* enabled, core clock, no interrupt: polled */
    device_init(uart_write);
    for (;;) {
        const int byte = uart_poll();
        if (byte >= 0) {
            device_byte((uint8_t)byte);
        }
        if ((SYST_CSR & SYST_COUNTFLAG) != 0u && ++ticks == TICKS_PER_HEARTBEAT) {
            ticks = 0u;
            device_heartbeat();
        }
    }
}
