/*
 * mem.c - memcpy and memset for the freestanding Cortex-M4 build (the
 * compiler may emit calls to them for struct copies and array clears).
 */
#include <stddef.h>
#include <stdint.h>

/** Copy n bytes from src to dst (regions do not overlap). */
void *memcpy(void *dst, const void *src, size_t n)
{
    uint8_t *d = dst;
    const uint8_t *s = src;
    while (n-- != 0u) {
        *d++ = *s++;
    }
    return dst;
}

/** Fill n bytes at dst with value. */
void *memset(void *dst, int value, size_t n)
{
    uint8_t *d = dst;
    while (n-- != 0u) {
        *d++ = (uint8_t)value;
    }
    return dst;
}
