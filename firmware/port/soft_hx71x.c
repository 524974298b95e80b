/* soft_hx71x.c - see soft_hx71x.h. */
#include "soft_hx71x.h"
#include "board.h"

void soft_hx71x_load(struct soft_hx71x *chip, const uint32_t *frames, uint16_t n_frames, uint8_t frame_pulses)
{
    chip->frames = frames;
    chip->n_frames = n_frames;
    chip->next = 0;
    chip->frame_pulses = frame_pulses;
    chip->bits_left = 0;
    chip->dout = 1;
    chip->shifting = 0;
}

int soft_hx71x_convert(struct soft_hx71x *chip)
{
    if (chip->next >= chip->n_frames)
        return 0;
    chip->shifting = chip->frames[chip->next++];
    chip->bits_left = chip->frame_pulses;
    chip->dout = 0;
    return 1;
}

static void pin_write(void *ctx, uint16_t pin, uint8_t level)
{
    struct soft_hx71x *chip = ctx;
    if (pin != SOFT_HX71X_SCLK_PIN || !level || chip->bits_left == 0)
        return;   /* only a rising SCLK edge during a frame shifts a bit out */
    chip->bits_left--;
    chip->dout = (uint8_t)((chip->shifting >> chip->bits_left) & 1u);
}

static uint8_t pin_read(void *ctx, uint16_t pin)
{
    const struct soft_hx71x *chip = ctx;
    return pin == SOFT_HX71X_DOUT_PIN ? chip->dout : 1u;
}

static void delay_ns(void *ctx, uint32_t ns)
{
    (void)ctx;
    board_delay_ns(ns);
}

static uint32_t time_now_ticks(void *ctx)
{
    (void)ctx;
    return board_now_ticks();
}

static uint32_t irq_save(void *ctx)
{
    (void)ctx;
    return tc_irq_save();
}

static void irq_restore(void *ctx, uint32_t saved)
{
    (void)ctx;
    tc_irq_restore(saved);
}

void soft_hx71x_hal(struct tc_hal *hal, struct soft_hx71x *chip)
{
    hal->ctx = chip;
    hal->pin_write = pin_write;
    hal->pin_read = pin_read;
    hal->delay_ns = delay_ns;
    hal->time_now_ticks = time_now_ticks;
    hal->spi_transfer = 0;
    hal->irq_save = irq_save;
    hal->irq_restore = irq_restore;
}
