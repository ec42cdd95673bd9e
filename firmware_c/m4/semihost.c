/*
 * semihost.c - ARM semihosting calls (see semihost.h).
 */
#include "semihost.h"

#define SYS_OPEN 0x01u
#define SYS_CLOSE 0x02u
#define SYS_WRITE0 0x04u
#define SYS_READ 0x06u
#define SYS_FLEN 0x0Cu
#define SYS_GET_CMDLINE 0x15u
#define SYS_EXIT_EXTENDED 0x20u
#define ADP_STOPPED_APPLICATION_EXIT 0x20026u

/** One semihosting call: operation in r0, argument block address in r1, result in r0. */
static long semihost_call(uint32_t op, const void *arg)
{
    register uint32_t r0 __asm__("r0") = op;
    register const void *r1 __asm__("r1") = arg;
    __asm__ volatile("bkpt 0xAB" : "+r"(r0) : "r"(r1) : "memory");
    return (long)(int32_t)r0;
}

void semihost_write0(const char *text)
{
    (void)semihost_call(SYS_WRITE0, text);
}

int semihost_cmdline(char *buffer, size_t capacity)
{
    uint32_t block[2] = {(uint32_t)buffer, (uint32_t)capacity};
    return (int)semihost_call(SYS_GET_CMDLINE, block);
}

long semihost_read_file(const char *path, uint8_t *buffer, size_t capacity)
{
    uint32_t length = 0u;
    uint32_t open_block[3];
    uint32_t block[3];
    long handle, size, left;

    while (path[length] != '\0') {
        length++;
    }
    open_block[0] = (uint32_t)path;
    open_block[1] = 1u; /* mode "rb" */
    open_block[2] = length;
    handle = semihost_call(SYS_OPEN, open_block);
    if (handle < 0) {
        return -1;
    }
    block[0] = (uint32_t)handle;
    size = semihost_call(SYS_FLEN, block);
    left = -1;
    if (size >= 0 && (size_t)size <= capacity) {
        block[1] = (uint32_t)buffer;
        block[2] = (uint32_t)size;
        left = semihost_call(SYS_READ, block); /* bytes NOT read */
    }
    (void)semihost_call(SYS_CLOSE, block);
    return (left == 0) ? size : -1;
}

void semihost_exit(int status)
{
    uint32_t block[2] = {ADP_STOPPED_APPLICATION_EXIT, (uint32_t)status};
    for (;;) {
        (void)semihost_call(SYS_EXIT_EXTENDED, block);
    }
}
