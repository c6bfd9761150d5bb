/* qemu_io.h - the semihosting vector files of the QEMU test images: ns2_in.bin
 * starts with a 4-byte magic and a u32 count, results go to ns2_out.bin. */
#ifndef QEMU_IO_H
#define QEMU_IO_H

#include <stdint.h>
#include <stdio.h>
#include <string.h>

/* Open both files and read the magic and count; 0 on success. */
static inline int qemu_open_vectors(const char magic[4], FILE **in, FILE **out, uint32_t *count)
{
    char got[4];
    *in = fopen("ns2_in.bin", "rb");
    *out = fopen("ns2_out.bin", "wb");
    return *in == NULL || *out == NULL || fread(got, 1, 4, *in) != 4 || memcmp(got, magic, 4) != 0 ||
        fread(count, sizeof *count, 1, *in) != 1;
}

#endif /* QEMU_IO_H */
