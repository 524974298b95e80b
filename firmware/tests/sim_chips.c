/* sim_chips.c - the simulated chips behind sim_chips.h. */
#include "sim_chips.h"
#include "hx71x.h"
#include "ads1220.h"

/* ---- HX711 / HX717 ---------------------------------------------------- */

static void hx_pin_write(void *ctx, uint16_t pin, uint8_t level)
{
    struct sim_hx71x *sim = ctx;
    if (pin != sim->sclk_pin || level == sim->sclk)
        return;
    sim->sclk = level;
    if (!sim->irq_disabled)
        sim->reads_with_irq_on++;
    if (level) {
        sim->sclk_rise_ticks = sim->now_ticks;
        if (sim->pulses_seen > 0) {
            uint32_t low_ns = sim->now_ticks - sim->sclk_fall_ticks;
            if (low_ns < sim->shortest_low_ns)
                sim->shortest_low_ns = low_ns;
        }
        if (sim->missed_edges > 0) {
            sim->missed_edges--;
            return;
        }
        sim->pulses_seen++;
        /* Rising edges 1..24 put the next data bit on DOUT, MSB first;
         * from the 25th on the chip holds DOUT high. */
        if (sim->pulses_seen <= HX71X_DATA_BITS)
            sim->dout = (uint8_t)(sim->conversion >> (HX71X_DATA_BITS - sim->pulses_seen) & 1u);
        else
            sim->dout = 1;
        return;
    }
    uint32_t high_ns = sim->now_ticks - sim->sclk_rise_ticks;
    sim->sclk_fall_ticks = sim->now_ticks;
    if (high_ns > 60000u) {
        /* Power-down, then power-up on the falling edge: the chip resets to
         * channel A gain 128 and starts a fresh conversion (DOUT high). */
        sim->power_cycles++;
        sim->pulses_seen = 0;
        sim->last_frame_pulses = 25;
        sim->dout = 1;
    } else if (high_ns > sim->longest_high_ns) {
        sim->longest_high_ns = high_ns;
    }
}

static uint8_t hx_pin_read(void *ctx, uint16_t pin)
{
    struct sim_hx71x *sim = ctx;
    sim->now_ticks += sim->ticks_per_pin_read;
    return pin == sim->dout_pin ? sim->dout : 0;
}

static void hx_delay_ns(void *ctx, uint32_t ns)
{
    struct sim_hx71x *sim = ctx;
    sim->now_ticks += ns;
}

static uint32_t hx_time_now(void *ctx)
{
    return ((struct sim_hx71x *)ctx)->now_ticks;
}

static uint32_t hx_irq_save(void *ctx)
{
    struct sim_hx71x *sim = ctx;
    uint32_t previous = sim->irq_disabled;
    sim->irq_disabled++;
    if (sim->irq_disabled > sim->irq_max_nesting)
        sim->irq_max_nesting = sim->irq_disabled;
    return previous;
}

static void hx_irq_restore(void *ctx, uint32_t saved_state)
{
    ((struct sim_hx71x *)ctx)->irq_disabled = (uint8_t)saved_state;
}

static void no_spi(void *ctx, uint8_t *data, uint8_t len)
{
    (void)ctx; (void)data; (void)len;
}

void sim_hx71x_init(struct sim_hx71x *sim, struct tc_hal *hal,
                    uint16_t sclk_pin, uint16_t dout_pin, uint32_t now_ticks)
{
    *sim = (struct sim_hx71x){ 0 };
    sim->sclk_pin = sclk_pin;
    sim->dout_pin = dout_pin;
    sim->now_ticks = now_ticks;
    sim->dout = 1;
    sim->shortest_low_ns = UINT32_MAX;
    *hal = (struct tc_hal){
        .ctx = sim, .pin_write = hx_pin_write, .pin_read = hx_pin_read,
        .delay_ns = hx_delay_ns, .time_now_ticks = hx_time_now,
        .spi_transfer = no_spi, .irq_save = hx_irq_save, .irq_restore = hx_irq_restore,
    };
}

void sim_hx71x_convert(struct sim_hx71x *sim, int32_t counts)
{
    if (sim->pulses_seen > HX71X_DATA_BITS)
        sim->last_frame_pulses = sim->pulses_seen;
    sim->conversion = (uint32_t)counts & 0xFFFFFFu;
    sim->pulses_seen = 0;
    sim->dout = 0;
}

/* ---- ADS1220 ---------------------------------------------------------- */

static void ads_pin_write(void *ctx, uint16_t pin, uint8_t level)
{
    struct sim_ads1220 *sim = ctx;
    if (pin == sim->cs_pin)
        sim->cs = level;
}

static uint8_t ads_pin_read(void *ctx, uint16_t pin)
{
    (void)ctx; (void)pin;
    return 0;
}

static void ads_delay_ns(void *ctx, uint32_t ns)
{
    ((struct sim_ads1220 *)ctx)->ns_since_reset += ns;
}

static uint32_t ads_time_now(void *ctx)
{
    return ((struct sim_ads1220 *)ctx)->ns_since_reset;
}

static uint32_t ads_irq_save(void *ctx)
{
    (void)ctx;
    return 0;
}

static void ads_irq_restore(void *ctx, uint32_t saved_state)
{
    (void)ctx; (void)saved_state;
}

static void ads_spi_transfer(void *ctx, uint8_t *data, uint8_t len)
{
    struct sim_ads1220 *sim = ctx;
    if (sim->cs != 0 || len == 0) {
        sim->protocol_errors++;
        return;
    }
    uint8_t command = data[0];
    if (sim->resets > 0 && sim->ns_since_reset < ADS1220_RESET_WAIT_NS)
        sim->command_too_soon = 1;
    if ((command & 0xFEu) == ADS1220_CMD_RESET) {
        for (int i = 0; i < 4; i++)
            sim->registers[i] = sim->reset_state[i];
        sim->started = 0;
        sim->resets++;
        sim->ns_since_reset = 0;
    } else if ((command & 0xFEu) == ADS1220_CMD_START) {
        sim->started = 1;
    } else if ((command & 0xF0u) == ADS1220_CMD_RREG || (command & 0xF0u) == ADS1220_CMD_WREG) {
        uint8_t first = (command >> 2) & 3u;
        uint8_t count = (uint8_t)((command & 3u) + 1u);
        if (len != 1u + count || first + count > 4) {
            sim->protocol_errors++;
            return;
        }
        for (uint8_t i = 0; i < count; i++) {
            uint8_t reg = (uint8_t)(first + i);
            if ((command & 0xF0u) == ADS1220_CMD_WREG)
                sim->registers[reg] = data[1 + i] & (uint8_t)~sim->stuck_low[reg];
            else
                data[1 + i] = sim->registers[reg];
        }
    } else if (command == 0x00 && len == 3 && sim->started) {
        uint32_t word = (uint32_t)sim->conversion & 0xFFFFFFu;
        data[0] = (uint8_t)(word >> 16);
        data[1] = (uint8_t)(word >> 8);
        data[2] = (uint8_t)word;
    } else {
        sim->protocol_errors++;
    }
}

void sim_ads1220_init(struct sim_ads1220 *sim, struct tc_hal *hal, uint16_t cs_pin)
{
    *sim = (struct sim_ads1220){ 0 };
    sim->cs_pin = cs_pin;
    sim->cs = 1;
    *hal = (struct tc_hal){
        .ctx = sim, .pin_write = ads_pin_write, .pin_read = ads_pin_read,
        .delay_ns = ads_delay_ns, .time_now_ticks = ads_time_now,
        .spi_transfer = ads_spi_transfer, .irq_save = ads_irq_save,
        .irq_restore = ads_irq_restore,
    };
}
