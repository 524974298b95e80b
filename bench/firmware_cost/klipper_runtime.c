/* The parts of Klipper's MCU runtime that sos_filter.c and trigger_analog.c call,
 * as the benchmark needs them: a fixed pool for oid_alloc (recording each
 * object's size: RAM per instance), a counting timer, a trsync that counts
 * triggers, no message output. */
#include <stdint.h>

struct trsync;
struct timer;
struct command_encoder;

uint32_t klipper_object_bytes[2];
uint32_t klipper_triggers;
uint32_t klipper_shutdowns;
static uint32_t pool[2][64];
static void *pool_type[2];
static volatile uint32_t now;

void *oid_alloc(uint8_t oid, void *type, uint16_t size)
{
    pool_type[oid] = type;
    klipper_object_bytes[oid] = size;
    return pool[oid];
}

void *oid_lookup(uint8_t oid, void *type)
{
    return pool_type[oid] == type ? pool[oid] : 0;
}

uint32_t timer_read_time(void)
{
    return now += 100;
}

uint8_t timer_is_before(uint32_t time1, uint32_t time2)
{
    return (int32_t)(time1 - time2) < 0;
}

void sched_add_timer(struct timer *t) { (void)t; }
void sched_del_timer(struct timer *t) { (void)t; }

struct trsync *trsync_oid_lookup(uint8_t oid)
{
    return (struct trsync *)(uintptr_t)(0x100u + oid);
}

void trsync_do_trigger(struct trsync *ts, uint8_t reason)
{
    (void)ts;
    (void)reason;
    klipper_triggers++;
}

const struct command_encoder *ctr_lookup_encoder(const char *str) { (void)str; return 0; }
uint8_t ctr_lookup_static_string(const char *str) { (void)str; return 0; }
void command_sendf(const struct command_encoder *ce, ...) { (void)ce; }

__attribute__((noreturn)) void sched_shutdown(uint_fast8_t reason)
{
    (void)reason;
    klipper_shutdowns++;
    for (;;)
        ;
}
