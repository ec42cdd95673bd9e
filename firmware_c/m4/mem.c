/*
 * mem.c - memcpy, memmove and memset for the freestanding Cortex-M4 build (the
 * compiler may emit calls to them for struct copies and array clears; VQF's std::copy
 * calls memmove), and the errno newlib's libm writes on a domain error (nobody reads it):
 * so the image needs libm and libgcc but not libc (whose reentrancy data is 1 kB of RAM).
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

/** Copy n bytes from src to dst; the regions may overlap. */
void *memmove(void *dst, const void *src, size_t n)
{
    uint8_t *d = dst;
    const uint8_t *s = src;
    if (d < s) {
        while (n-- != 0u) {
            *d++ = *s++;
        }
    } else {
        while (n-- != 0u) {
            d[n] = s[n];
        }
    }
    return dst;
}

/** errno's storage, for newlib's libm. */
int *__errno(void)
{
    static int error;
    return &error;
}
