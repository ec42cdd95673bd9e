/*
 * uart.h - UART0 of the mps2-an386 board (ARM CMSDK APB UART at 0x40004000), polled.
 *
 * Registers: DATA +0x00; STATE +0x04 (bit 0 TX full, bit 1 RX full); CTRL +0x08 (bit 0 TX
 * enable, bit 1 RX enable); BAUDDIV +0x10 (>= 16). A real board's UART or USB CDC driver
 * replaces these three functions; the link above them does not change.
 */
#ifndef UART_H
#define UART_H

#include <stddef.h>
#include <stdint.h>

/** Enable TX and RX (BAUDDIV 16: under QEMU the rate is not modelled). */
void uart_init(void);

/**
 * Let a received byte wake the core from WFI: the RX interrupt on, through the NVIC (UART0 RX is
 * IRQ 0 on mps2-an386), never taken (the caller masks interrupts with PRIMASK).
 */
void uart_wake_on_rx(void);

/** Clear the RX wake-up (before draining the received bytes, so none is slept through). */
void uart_clear_wake(void);

/** The received byte, or -1 if none is waiting. */
int uart_poll(void);

/** Send n bytes, waiting while the transmitter is full. */
void uart_write(const uint8_t *data, size_t n);

#endif /* UART_H */
