/* startup.h - what startup.c offers the app. */
#ifndef TAPCELL_PORT_STARTUP_H
#define TAPCELL_PORT_STARTUP_H

#include <stdint.h>

#define STACK_PAINT 0xC5C5C5C5u

/* Deepest stack use since reset, from the painted stack. */
uint32_t stack_high_water_bytes(void);
uint32_t stack_size_bytes(void);

#endif
