/* semihost.h - ARM semihosting (BKPT 0xAB): console output and the exit status.
 * QEMU implements it with -semihosting-config enable=on; the rp2040js runner
 * (rp2040/run.mjs) implements the same three calls. No divide anywhere: numbers
 * are printed in hexadecimal and converted on the host. */
#ifndef TAPCELL_PORT_SEMIHOST_H
#define TAPCELL_PORT_SEMIHOST_H

#include <stdint.h>

void semihost_puts(const char *text);
/* "key value\n" with value in hex (0x...). */
void semihost_put_hex(const char *key, uint32_t value);
/* Ends the emulation with this exit status (0 = every check passed). */
void semihost_exit(uint32_t status) __attribute__((noreturn));

#endif
