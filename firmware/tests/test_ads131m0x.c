/* ADS131M02/M04: CRC, frame decoding (channel, sign, CRC errors, sticky reset), register words. */
#include "unit.h"
#include "ads131m0x.h"

/* A frame as the chip sends it: STATUS, the channel words, then the CRC of all of them.
 * 0x0103: 24-bit words (WLENGTH 01b), both DRDY bits set, no reset. */
static void make_frame(uint8_t *frame, uint8_t channels, uint16_t status, const int32_t *values)
{
    frame[0] = (uint8_t)(status >> 8);
    frame[1] = (uint8_t)status;
    frame[2] = 0;
    for (uint8_t ch = 0; ch < channels; ch++) {
        uint32_t word = (uint32_t)values[ch] & 0xFFFFFFu;
        frame[3 + 3 * ch] = (uint8_t)(word >> 16);
        frame[4 + 3 * ch] = (uint8_t)(word >> 8);
        frame[5 + 3 * ch] = (uint8_t)word;
    }
    uint8_t covered = (uint8_t)(3 * (1 + channels));
    uint16_t crc = ads131m0x_crc16(frame, covered);
    frame[covered] = (uint8_t)(crc >> 8);
    frame[covered + 1] = (uint8_t)crc;
    frame[covered + 2] = 0;
}

TEST(ads131m0x_crc16_is_ccitt_with_initial_ffff)
{
    static const uint8_t check[9] = { '1', '2', '3', '4', '5', '6', '7', '8', '9' };
    CHECK_EQ_INT(ads131m0x_crc16(check, sizeof(check)), 0x29B1);  /* the standard check value */
    CHECK_EQ_INT(ads131m0x_crc16(check, 0), 0xFFFF);
}

TEST(ads131m0x_frame_sizes)
{
    CHECK_EQ_INT(ads131m0x_frame_bytes(2), 12);
    CHECK_EQ_INT(ads131m0x_frame_bytes(4), 18);
    struct ads131m0x_reader reader;
    CHECK_EQ_INT(ads131m0x_reader_init(&reader, 3, 0), ADS131M0X_ERR_BAD_CHANNELS);
    CHECK_EQ_INT(ads131m0x_reader_init(&reader, 2, 2), ADS131M0X_ERR_BAD_CHANNEL);
    CHECK_EQ_INT(ads131m0x_reader_init(&reader, 4, 3), ADS131M0X_OK);
}

TEST(ads131m0x_decodes_the_chosen_channel_with_its_sign)
{
    struct ads131m0x_reader reader;
    uint8_t frame[ADS131M0X_MAX_FRAME_BYTES];
    const int32_t values[4] = { 1234567, -38000, -8388608, 8388607 };
    int32_t counts = 0;
    for (uint8_t ch = 0; ch < 4; ch++) {
        CHECK_EQ_INT(ads131m0x_reader_init(&reader, 4, ch), ADS131M0X_OK);
        make_frame(frame, 4, 0x0103, values);
        CHECK_EQ_INT(ads131m0x_decode_frame(&reader, frame, &counts), ADS131M0X_OK);
        CHECK_EQ_INT(counts, values[ch]);
    }
    CHECK_EQ_INT(ads131m0x_reader_init(&reader, 2, 1), ADS131M0X_OK);
    make_frame(frame, 2, 0x0103, values);
    CHECK_EQ_INT(ads131m0x_decode_frame(&reader, frame, &counts), ADS131M0X_OK);
    CHECK_EQ_INT(counts, -38000);
}

TEST(ads131m0x_a_flipped_bit_anywhere_fails_the_crc_of_that_frame_only)
{
    struct ads131m0x_reader reader;
    uint8_t frame[ADS131M0X_MAX_FRAME_BYTES];
    const int32_t values[2] = { -38000, 77 };
    CHECK_EQ_INT(ads131m0x_reader_init(&reader, 2, 0), ADS131M0X_OK);
    int failures = 0;
    for (uint8_t byte = 0; byte < 11; byte++) {  /* STATUS, both words and the CRC itself */
        for (uint8_t bit = 0; bit < 8; bit++) {
            int32_t counts = 12345;
            make_frame(frame, 2, 0x0103, values);
            frame[byte] ^= (uint8_t)(1u << bit);
            if (ads131m0x_decode_frame(&reader, frame, &counts) == ADS131M0X_ERR_CRC && counts == 12345)
                failures++;
        }
    }
    CHECK_EQ_INT(failures, 11 * 8);
    int32_t counts = 0;
    make_frame(frame, 2, 0x0103, values);
    CHECK_EQ_INT(ads131m0x_decode_frame(&reader, frame, &counts), ADS131M0X_OK);
    CHECK_EQ_INT(counts, -38000);
}

TEST(ads131m0x_a_reset_is_sticky_until_restart)
{
    struct ads131m0x_reader reader;
    uint8_t frames[3 * 12];
    const int32_t values[2] = { 500, 600 };
    CHECK_EQ_INT(ads131m0x_reader_init(&reader, 2, 1), ADS131M0X_OK);
    make_frame(frames, 2, 0x0103, values);
    make_frame(frames + 12, 2, 0x0103 | ADS131M0X_STATUS_RESET_BIT, values);
    make_frame(frames + 24, 2, 0x0103, values);
    int32_t counts[3];
    uint8_t status[3];
    CHECK_EQ_INT(ads131m0x_decode_frames(&reader, frames, 3, counts, status), 1);
    CHECK_EQ_INT(status[0], ADS131M0X_OK);
    CHECK_EQ_INT(counts[0], 600);
    CHECK_EQ_INT(status[1], ADS131M0X_ERR_RESET);
    CHECK_EQ_INT(status[2], ADS131M0X_ERR_RESET);  /* a clean frame after a reset is not trusted */
    CHECK_EQ_INT(counts[2], 0);
    ads131m0x_reader_restart(&reader);
    CHECK_EQ_INT(ads131m0x_decode_frames(&reader, frames + 24, 1, counts, status), 1);
    CHECK_EQ_INT(counts[0], 600);
}

TEST(ads131m0x_register_words)
{
    struct ads131m0x_registers regs;
    /* M02, channel 0, OSR 8192 (500 sps at 8.192 MHz), gain 128, no chop. */
    CHECK_EQ_INT(ads131m0x_register_words(2, 0, 8192, 128, 0, 16, &regs), ADS131M0X_OK);
    CHECK_EQ_INT(regs.mode, 0x0100);
    CHECK_EQ_INT(regs.clock, 0x0100 | 6 << 2 | 0x2);
    CHECK_EQ_INT(regs.gain1, 0x7777);
    CHECK_EQ_INT(regs.cfg, 0);
    /* M04, channel 3, OSR 64 (turbo), gain 1, global chop with a 16-clock delay. */
    CHECK_EQ_INT(ads131m0x_register_words(4, 3, 64, 1, 1, 16, &regs), ADS131M0X_OK);
    CHECK_EQ_INT(regs.clock, 0x0800 | 0x20 | 0x2);
    CHECK_EQ_INT(regs.gain1, 0x0000);
    CHECK_EQ_INT(regs.cfg, 3 << 9 | 0x100);
    CHECK_EQ_INT(ads131m0x_register_words(4, 1, 16384, 4, 1, 65536, &regs), ADS131M0X_OK);
    CHECK_EQ_INT(regs.clock, 0x0200 | 7 << 2 | 0x2);
    CHECK_EQ_INT(regs.gain1, 0x2222);
    CHECK_EQ_INT(regs.cfg, 15 << 9 | 0x100);
    CHECK_EQ_INT(ads131m0x_register_words(2, 0, 96, 128, 0, 16, &regs), ADS131M0X_ERR_BAD_OSR);
    CHECK_EQ_INT(ads131m0x_register_words(2, 0, 32, 128, 0, 16, &regs), ADS131M0X_ERR_BAD_OSR);
    CHECK_EQ_INT(ads131m0x_register_words(2, 0, 128, 3, 0, 16, &regs), ADS131M0X_ERR_BAD_GAIN);
    CHECK_EQ_INT(ads131m0x_register_words(2, 0, 128, 128, 1, 1, &regs), ADS131M0X_ERR_BAD_CHOP_DELAY);
    CHECK_EQ_INT(ads131m0x_register_words(2, 2, 128, 128, 0, 16, &regs), ADS131M0X_ERR_BAD_CHANNEL);
}
