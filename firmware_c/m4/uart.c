/*
 * uart.c - polled CMSDK UART0 (see uart.h).
 */
#include "uart.h"

#define UART0_BASE 0x40004000u
#define UART_DATA (*(volatile uint32_t *)(UART0_BASE + 0x00u))
#define UART_STATE (*(volatile uint32_t *)(UART0_BASE + 0x04u))
#define UART_CTRL (*(volatile uint32_t *)(UART0_BASE + 0x08u))
#define UART_INTCLEAR (*(volatile uint32_t *)(UART0_BASE + 0x0Cu))
#define UART_BAUDDIV (*(volatile uint32_t *)(UART0_BASE + 0x10u))
#define NVIC_ISER0 (*(volatile uint32_t *)0xE000E100u)
#define NVIC_ICPR0 (*(volatile uint32_t *)0xE000E280u)
#define UART0_RX_IRQ 0u
#define CTRL_RX_INT 0x8u
#define INT_RX 0x2u
#define STATE_TX_FULL 0x1u
#define STATE_RX_FULL 0x2u

void uart_init(void)
{
    UART_BAUDDIV = 16u;
    UART_CTRL = 0x3u; /* TX and RX enable */
}

void uart_wake_on_rx(void)
{
    UART_CTRL |= CTRL_RX_INT;
    NVIC_ISER0 = 1u << UART0_RX_IRQ;
}

void uart_clear_wake(void)
{
    UART_INTCLEAR = INT_RX;
    NVIC_ICPR0 = 1u << UART0_RX_IRQ;
}

int uart_poll(void)
{
    if ((UART_STATE & STATE_RX_FULL) == 0u) {
        return -1;
    }
    return (int)(UART_DATA & 0xFFu);
}

void uart_write(const uint8_t *data, size_t n)
{
    size_t i;
    for (i = 0u; i < n; i++) {
        while ((UART_STATE & STATE_TX_FULL) != 0u) {
        }
        UART_DATA = data[i];
    }
}
