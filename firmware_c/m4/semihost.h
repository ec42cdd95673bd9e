/*
 * semihost.h - ARM semihosting (bkpt 0xAB) calls used by the QEMU harnesses.
 *
 * QEMU answers them with -semihosting-config enable=on,target=native:
 * console output goes to QEMU's stderr, files are the host's files.
 */
#ifndef SEMIHOST_H
#define SEMIHOST_H

#include <stddef.h>
#include <stdint.h>

/** Print a NUL-terminated string on the debug console (SYS_WRITE0). */
void semihost_write0(const char *text);

/** Command line given with -semihosting-config ...,arg=...; returns 0 on success (SYS_GET_CMDLINE). */
int semihost_cmdline(char *buffer, size_t capacity);

/**
 * Read a whole host file into buffer; returns its length in bytes, or -1 if it
 * cannot be opened, read or does not fit (SYS_OPEN, SYS_FLEN, SYS_READ, SYS_CLOSE).
 */
long semihost_read_file(const char *path, uint8_t *buffer, size_t capacity);

/** End the QEMU run with this exit status (SYS_EXIT_EXTENDED). */
__attribute__((noreturn)) void semihost_exit(int status);

#endif /* SEMIHOST_H */
