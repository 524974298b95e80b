/* hx71x.c - HX711 / HX717 frame decoding and bit-bang read through the HAL.
 * See hx71x.h for the protocol. No allocation, no floats, no globals. */
#include "hx71x.h"

uint8_t hx71x_frame_pulses(uint8_t chip, uint8_t gain)
{
    /* Pulses per frame, indexed [chip][gain]; 0 = not offered by the chip. */
    static const uint8_t pulses[2][5] = {
        /*            A-128 B-32 A-64 B-64 B-8 */
        /* HX711 */ { 25,   26,  27,  0,   0  },
        /* HX717 */ { 25,   0,   27,  26,  28 },
    };
    if (chip > HX71X_CHIP_HX717 || gain > HX71X_GAIN_B_8)
        return 0;
    return pulses[chip][gain];
}

enum hx71x_status hx71x_check_sample_rate(uint8_t chip, uint16_t sample_rate_sps)
{
    /* The rate is set by the RATE pin(s), not by software, so this only
     * guards against a config that does not match any strapping. */
    switch (chip) {
    case HX71X_CHIP_HX711:
        if (sample_rate_sps == 10 || sample_rate_sps == 80)
            return HX71X_OK;
        return HX71X_ERR_BAD_SAMPLE_RATE;
    case HX71X_CHIP_HX717:
        if (sample_rate_sps == 10 || sample_rate_sps == 20
            || sample_rate_sps == 80 || sample_rate_sps == 320)
            return HX71X_OK;
        return HX71X_ERR_BAD_SAMPLE_RATE;
    default:
        return HX71X_ERR_BAD_CHIP;
    }
}

enum hx71x_status hx71x_decode_frame(uint32_t frame_bits, uint8_t frame_pulses,
                                     int32_t *counts)
{
    if (frame_pulses < HX71X_DATA_BITS || frame_pulses > HX71X_DATA_BITS + 4)
        return HX71X_ERR_BAD_FRAME_LENGTH;
    uint8_t trailing_bits = (uint8_t)(frame_pulses - HX71X_DATA_BITS);
    uint32_t trailing_mask = (1u << trailing_bits) - 1u;
    if ((frame_bits & trailing_mask) != trailing_mask)
        return HX71X_ERR_DESYNC;
    *counts = tc_sign_extend_24(frame_bits >> trailing_bits);
    return HX71X_OK;
}

enum hx71x_status hx71x_decode_frames(const uint32_t *frames, size_t count,
                                      uint8_t frame_pulses, int32_t *counts_out,
                                      size_t *decoded_count)
{
    for (size_t i = 0; i < count; i++) {
        enum hx71x_status status =
            hx71x_decode_frame(frames[i], frame_pulses, &counts_out[i]);
        if (status != HX71X_OK) {
            *decoded_count = i;
            return status;
        }
    }
    *decoded_count = count;
    return HX71X_OK;
}

/* n / d by shift and subtract: ARMv6-M has no divide instruction, and this keeps
 * the libgcc helper (__aeabi_uidiv) out of the image. Runs once, at init. */
static uint32_t divide_u32(uint32_t n, uint32_t d)
{
    uint32_t quotient = 0, remainder = 0;
    for (int bit = 31; bit >= 0; bit--) {
        remainder = (remainder << 1) | ((n >> bit) & 1u);
        if (remainder >= d) {
            remainder -= d;
            quotient |= 1u << bit;
        }
    }
    return quotient;
}

enum hx71x_status hx71x_init(struct hx71x *dev, const struct tc_hal *hal,
                             const struct hx71x_config *config)
{
    enum hx71x_status rate_status =
        hx71x_check_sample_rate(config->chip, config->sample_rate_sps);
    if (rate_status != HX71X_OK)
        return rate_status;
    uint8_t frame_pulses = hx71x_frame_pulses(config->chip, config->gain);
    if (frame_pulses == 0)
        return HX71X_ERR_BAD_GAIN;
    uint32_t period_ticks = divide_u32(config->ticks_per_s, config->sample_rate_sps);
    if (period_ticks == 0)
        return HX71X_ERR_BAD_TICK_RATE;

    dev->hal = hal;
    dev->sclk_pin = config->sclk_pin;
    dev->dout_pin = config->dout_pin;
    dev->frame_pulses = frame_pulses;
    dev->settling_left = 0;
    dev->sample_period_ticks = period_ticks;
    dev->error = HX71X_ERR_NOT_STARTED;
    return HX71X_OK;
}

void hx71x_start(struct hx71x *dev)
{
    const struct tc_hal *hal = dev->hal;
    hal->pin_write(hal->ctx, dev->sclk_pin, 1);
    hal->delay_ns(hal->ctx, HX71X_POWER_DOWN_NS);
    hal->pin_write(hal->ctx, dev->sclk_pin, 0);
    dev->settling_left = HX71X_SETTLING_SAMPLES;
    dev->error = HX71X_OK;
}

uint8_t hx71x_is_ready(const struct hx71x *dev)
{
    const struct tc_hal *hal = dev->hal;
    return hal->pin_read(hal->ctx, dev->dout_pin) == 0;
}

/* One SCLK pulse, then sample DOUT. The chip changes DOUT on the rising edge
 * and holds it until the next one, so reading after the falling edge is safe.
 * Interrupts are off only for the high phase: a stretched high phase (over
 * 60 us) would power the chip down mid-frame. */
static uint8_t clock_one_bit(const struct hx71x *dev)
{
    const struct tc_hal *hal = dev->hal;
    uint32_t irq_state = hal->irq_save(hal->ctx);
    hal->pin_write(hal->ctx, dev->sclk_pin, 1);
    hal->delay_ns(hal->ctx, HX71X_PULSE_NS);
    hal->pin_write(hal->ctx, dev->sclk_pin, 0);
    hal->irq_restore(hal->ctx, irq_state);
    uint8_t bit = hal->pin_read(hal->ctx, dev->dout_pin) ? 1u : 0u;
    hal->delay_ns(hal->ctx, HX71X_PULSE_NS);
    return bit;
}

enum hx71x_status hx71x_read(struct hx71x *dev, uint32_t ready_ticks,
                             int32_t *counts)
{
    if (dev->error != HX71X_OK)
        return dev->error;
    if (!hx71x_is_ready(dev))
        return HX71X_ERR_NOT_READY;

    /* Always clock the whole frame, even if it will be rejected: the trailing
     * pulses choose the next conversion's gain and finish the handshake. */
    uint32_t frame_bits = 0;
    for (uint8_t i = 0; i < dev->frame_pulses; i++)
        frame_bits = (frame_bits << 1) | clock_one_bit(dev);

    /* Lateness first: a frame overlapping the next conversion may also look
     * like a desync, and lateness is the cause worth reporting. */
    uint32_t elapsed_ticks = dev->hal->time_now_ticks(dev->hal->ctx) - ready_ticks;
    if (elapsed_ticks >= dev->sample_period_ticks) {
        dev->error = HX71X_ERR_LATE_READ;
        return dev->error;
    }
    int32_t value;
    enum hx71x_status status = hx71x_decode_frame(frame_bits, dev->frame_pulses, &value);
    if (status != HX71X_OK) {
        dev->error = status;
        return status;
    }
    if (dev->settling_left > 0) {
        dev->settling_left--;
        return HX71X_SETTLING;
    }
    *counts = value;
    return HX71X_OK;
}
