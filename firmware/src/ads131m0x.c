/* ads131m0x.c - ADS131M02/M04 frame checks and register words. See ads131m0x.h.
 * No allocation, no floats, no globals. */
#include "ads131m0x.h"
#include "hal.h"

uint16_t ads131m0x_crc16(const uint8_t *data, size_t len)
{
    uint16_t crc = ADS131M0X_CRC_INIT;
    for (size_t i = 0; i < len; i++) {
        crc ^= (uint16_t)((uint16_t)data[i] << 8);
        for (uint8_t bit = 0; bit < 8; bit++)
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ ADS131M0X_CRC_POLY) : (uint16_t)(crc << 1);
    }
    return crc;
}

uint8_t ads131m0x_frame_bytes(uint8_t channels)
{
    return (uint8_t)(ADS131M0X_WORD_BYTES * (channels + 2u));
}

enum ads131m0x_status ads131m0x_reader_init(struct ads131m0x_reader *reader, uint8_t channels,
                                            uint8_t channel)
{
    if (channels != 2u && channels != 4u)
        return ADS131M0X_ERR_BAD_CHANNELS;
    if (channel >= channels)
        return ADS131M0X_ERR_BAD_CHANNEL;
    reader->channels = channels;
    reader->channel = channel;
    reader->reset_seen = 0;
    return ADS131M0X_OK;
}

void ads131m0x_reader_restart(struct ads131m0x_reader *reader)
{
    reader->reset_seen = 0;
}

static uint32_t word_at(const uint8_t *bytes)
{
    return (uint32_t)bytes[0] << 16 | (uint32_t)bytes[1] << 8 | bytes[2];
}

enum ads131m0x_status ads131m0x_decode_frame(struct ads131m0x_reader *reader, const uint8_t *frame,
                                             int32_t *counts)
{
    /* The CRC covers the STATUS word and every channel word, pad bytes included. */
    size_t covered = ADS131M0X_WORD_BYTES * (1u + reader->channels);
    uint16_t sent_crc = (uint16_t)(frame[covered] << 8 | frame[covered + 1u]);
    if (ads131m0x_crc16(frame, covered) != sent_crc)
        return ADS131M0X_ERR_CRC;
    /* Only a frame whose CRC holds can be believed about a reset. */
    uint16_t status = (uint16_t)(frame[0] << 8 | frame[1]);
    if (status & ADS131M0X_STATUS_RESET_BIT)
        reader->reset_seen = 1;
    if (reader->reset_seen)
        return ADS131M0X_ERR_RESET;
    *counts = tc_sign_extend_24(word_at(frame + ADS131M0X_WORD_BYTES * (1u + reader->channel)));
    return ADS131M0X_OK;
}

size_t ads131m0x_decode_frames(struct ads131m0x_reader *reader, const uint8_t *frames, size_t count,
                               int32_t *counts_out, uint8_t *status_out)
{
    size_t good = 0;
    uint8_t frame_bytes = ads131m0x_frame_bytes(reader->channels);
    for (size_t i = 0; i < count; i++) {
        int32_t counts = 0;
        enum ads131m0x_status status = ads131m0x_decode_frame(reader, frames + i * frame_bytes, &counts);
        counts_out[i] = counts;
        status_out[i] = (uint8_t)status;
        if (status == ADS131M0X_OK)
            good++;
    }
    return good;
}

/* log2(value) when value is a power of two in [low, high], else -1. */
static int8_t power_of_two_code(uint32_t value, uint32_t low, uint32_t high)
{
    if (value < low || value > high || (value & (value - 1u)) != 0)
        return -1;
    int8_t code = 0;
    while ((1ul << code) != value)
        code++;
    return code;
}

enum ads131m0x_status ads131m0x_register_words(uint8_t channels, uint8_t channel, uint16_t osr,
                                               uint8_t gain, uint8_t global_chop, uint32_t chop_delay,
                                               struct ads131m0x_registers *out)
{
    if (channels != 2u && channels != 4u)
        return ADS131M0X_ERR_BAD_CHANNELS;
    if (channel >= channels)
        return ADS131M0X_ERR_BAD_CHANNEL;
    int8_t gain_code = power_of_two_code(gain, 1u, 128u);
    if (gain_code < 0)
        return ADS131M0X_ERR_BAD_GAIN;
    int8_t osr_log = power_of_two_code(osr, 64u, 16384u);
    if (osr_log < 0)
        return ADS131M0X_ERR_BAD_OSR;
    uint16_t cfg = 0;
    if (global_chop) {
        int8_t delay_log = power_of_two_code(chop_delay, 2u, 65536ul);
        if (delay_log < 0)
            return ADS131M0X_ERR_BAD_CHOP_DELAY;
        cfg = (uint16_t)((uint16_t)(delay_log - 1) << 9 | ADS131M0X_CFG_GC_EN);
    }
    /* OSR 128 .. 16384 are codes 0 .. 7 in OSR[2:0]; 64 is the turbo bit with code 0. */
    uint16_t osr_bits = osr == 64u ? ADS131M0X_CLOCK_TBM : (uint16_t)((uint16_t)(osr_log - 7) << 2);
    uint16_t gain_nibble = (uint16_t)gain_code;
    out->mode = ADS131M0X_MODE_24BIT;
    /* Only the load cell's channel is enabled (CHn_EN is bit 8 + n). */
    out->clock = (uint16_t)((1u << (8u + channel)) | osr_bits | ADS131M0X_CLOCK_PWR_HIGH_RESOLUTION);
    out->gain1 = (uint16_t)(gain_nibble | gain_nibble << 4 | gain_nibble << 8 | gain_nibble << 12);
    out->cfg = cfg;
    return ADS131M0X_OK;
}
