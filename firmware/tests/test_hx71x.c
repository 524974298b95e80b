/* HX711 / HX717: frame decode, gain pulses, rates, and the bit-bang read
 * against a simulated chip (desync, late read, sticky errors, restart). */
#include "unit.h"
#include "hx71x.h"
#include "sim_chips.h"

#define SCLK_PIN 3
#define DOUT_PIN 4

/* A started driver on a simulated chip, past its settling samples. */
struct rig {
    struct sim_hx71x sim;
    struct tc_hal hal;
    struct hx71x dev;
};

static enum hx71x_status rig_setup(struct rig *rig, uint8_t chip, uint8_t gain,
                                   uint16_t rate_sps, uint32_t start_ticks)
{
    sim_hx71x_init(&rig->sim, &rig->hal, SCLK_PIN, DOUT_PIN, start_ticks);
    struct hx71x_config config = {
        .chip = chip, .gain = gain, .sample_rate_sps = rate_sps,
        .ticks_per_s = SIM_TICKS_PER_S, .sclk_pin = SCLK_PIN, .dout_pin = DOUT_PIN,
    };
    return hx71x_init(&rig->dev, &rig->hal, &config);
}

/* Convert `counts` on the chip and read it right away. */
static enum hx71x_status rig_sample(struct rig *rig, int32_t counts, int32_t *out)
{
    sim_hx71x_convert(&rig->sim, counts);
    return hx71x_read(&rig->dev, rig->sim.now_ticks, out);
}

static void rig_start_and_settle(struct rig *rig, int *unit_failed_)
{
    hx71x_start(&rig->dev);
    int32_t ignored = 12345;
    for (unsigned i = 0; i < HX71X_SETTLING_SAMPLES; i++)
        CHECK_EQ_INT(rig_sample(rig, 7, &ignored), HX71X_SETTLING);
    CHECK_EQ_INT(ignored, 12345);
}

TEST(hx71x_pulses_per_gain_for_both_chips)
{
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX711, HX71X_GAIN_A_128), 25);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX711, HX71X_GAIN_B_32), 26);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX711, HX71X_GAIN_A_64), 27);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX711, HX71X_GAIN_B_64), 0);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX711, HX71X_GAIN_B_8), 0);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX717, HX71X_GAIN_A_128), 25);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX717, HX71X_GAIN_B_64), 26);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX717, HX71X_GAIN_A_64), 27);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX717, HX71X_GAIN_B_8), 28);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX717, HX71X_GAIN_B_32), 0);
    CHECK_EQ_INT(hx71x_frame_pulses(2, HX71X_GAIN_A_128), 0);
    CHECK_EQ_INT(hx71x_frame_pulses(HX71X_CHIP_HX711, 5), 0);
}

TEST(hx71x_sample_rates_per_chip)
{
    for (uint32_t rate = 0; rate <= 400; rate++) {
        int hx711_ok = rate == 10 || rate == 80;
        int hx717_ok = rate == 10 || rate == 20 || rate == 80 || rate == 320;
        CHECK_EQ_INT(hx71x_check_sample_rate(HX71X_CHIP_HX711, (uint16_t)rate),
                     hx711_ok ? HX71X_OK : HX71X_ERR_BAD_SAMPLE_RATE);
        CHECK_EQ_INT(hx71x_check_sample_rate(HX71X_CHIP_HX717, (uint16_t)rate),
                     hx717_ok ? HX71X_OK : HX71X_ERR_BAD_SAMPLE_RATE);
    }
    CHECK_EQ_INT(hx71x_check_sample_rate(7, 80), HX71X_ERR_BAD_CHIP);
}

TEST(hx71x_decode_full_scale_and_sign)
{
    int32_t counts = 0;
    /* 25-pulse frames: value << 1 | trailing 1. */
    CHECK_EQ_INT(hx71x_decode_frame(0x7FFFFFu << 1 | 1u, 25, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 8388607);
    CHECK_EQ_INT(hx71x_decode_frame(0x800000u << 1 | 1u, 25, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, -8388608);
    CHECK_EQ_INT(hx71x_decode_frame(0xFFFFFFu << 1 | 1u, 25, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, -1);
    CHECK_EQ_INT(hx71x_decode_frame(0x000001u << 1 | 1u, 25, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 1);
    CHECK_EQ_INT(hx71x_decode_frame(0, 24, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 0);
    /* 28-pulse frame: 4 trailing ones. */
    CHECK_EQ_INT(hx71x_decode_frame(0xFEDCBAu << 4 | 0xFu, 28, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 0xFEDCBA - 0x1000000);
    /* Bits above the frame are ignored. */
    CHECK_EQ_INT(hx71x_decode_frame(0xF0000000u | 0x123456u, 24, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 0x123456);
}

TEST(hx71x_decode_desync_on_any_zero_trailing_bit)
{
    for (uint8_t pulses = 25; pulses <= 28; pulses++) {
        uint8_t trailing = (uint8_t)(pulses - 24);
        for (uint32_t tail = 0; tail < (1u << trailing); tail++) {
            int32_t counts = 99;
            uint32_t frame = 0x123456u << trailing | tail;
            int all_ones = tail == (1u << trailing) - 1u;
            CHECK_EQ_INT(hx71x_decode_frame(frame, pulses, &counts),
                         all_ones ? HX71X_OK : HX71X_ERR_DESYNC);
            CHECK_EQ_INT(counts, all_ones ? 0x123456 : 99);
        }
    }
    int32_t counts = 0;
    CHECK_EQ_INT(hx71x_decode_frame(0, 23, &counts), HX71X_ERR_BAD_FRAME_LENGTH);
    CHECK_EQ_INT(hx71x_decode_frame(0, 29, &counts), HX71X_ERR_BAD_FRAME_LENGTH);
}

TEST(hx71x_decode_frames_batch_stops_at_first_desync)
{
    const uint32_t frames[4] = { 0x000002u << 2 | 3u, 0xFFFFFEu << 2 | 3u,
                                 0x000010u << 2 | 1u, 0x000001u << 2 | 3u };
    int32_t counts[4] = { 0, 0, 0, 0 };
    size_t decoded = 99;
    CHECK_EQ_INT(hx71x_decode_frames(frames, 4, 26, counts, &decoded), HX71X_ERR_DESYNC);
    CHECK_EQ_INT(decoded, 2);
    CHECK_EQ_INT(counts[0], 2);
    CHECK_EQ_INT(counts[1], -2);
    CHECK_EQ_INT(hx71x_decode_frames(frames, 2, 26, counts, &decoded), HX71X_OK);
    CHECK_EQ_INT(decoded, 2);
}

TEST(hx71x_init_rejects_bad_config)
{
    struct rig rig;
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX711, HX71X_GAIN_B_8, 80, 0), HX71X_ERR_BAD_GAIN);
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX717, HX71X_GAIN_B_32, 320, 0), HX71X_ERR_BAD_GAIN);
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX711, HX71X_GAIN_A_128, 320, 0),
                 HX71X_ERR_BAD_SAMPLE_RATE);
    CHECK_EQ_INT(rig_setup(&rig, 9, HX71X_GAIN_A_128, 80, 0), HX71X_ERR_BAD_CHIP);
    sim_hx71x_init(&rig.sim, &rig.hal, SCLK_PIN, DOUT_PIN, 0);
    struct hx71x_config slow_timer = {
        .chip = HX71X_CHIP_HX717, .gain = HX71X_GAIN_A_128, .sample_rate_sps = 320,
        .ticks_per_s = 100, .sclk_pin = SCLK_PIN, .dout_pin = DOUT_PIN,
    };
    CHECK_EQ_INT(hx71x_init(&rig.dev, &rig.hal, &slow_timer), HX71X_ERR_BAD_TICK_RATE);
}

TEST(hx71x_read_before_start_is_refused)
{
    struct rig rig;
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX711, HX71X_GAIN_A_128, 80, 0), HX71X_OK);
    int32_t counts = 5;
    CHECK_EQ_INT(rig_sample(&rig, 100, &counts), HX71X_ERR_NOT_STARTED);
    CHECK_EQ_INT(rig.sim.pulses_seen, 0);
    CHECK_EQ_INT(counts, 5);
}

TEST(hx71x_start_power_cycles_and_discards_settling_samples)
{
    struct rig rig;
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX717, HX71X_GAIN_B_8, 320, 0), HX71X_OK);
    hx71x_start(&rig.dev);
    CHECK_EQ_INT(rig.sim.power_cycles, 1);
    CHECK_EQ_INT(rig.sim.sclk, 0);
    int32_t counts = 0;
    CHECK_EQ_INT(rig_sample(&rig, 1000, &counts), HX71X_SETTLING);
    CHECK_EQ_INT(rig_sample(&rig, 1000, &counts), HX71X_SETTLING);
    CHECK_EQ_INT(rig_sample(&rig, 1000, &counts), HX71X_SETTLING);
    CHECK_EQ_INT(rig_sample(&rig, 1000, &counts), HX71X_SETTLING);
    CHECK_EQ_INT(counts, 0);
    CHECK_EQ_INT(rig_sample(&rig, 1000, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 1000);
}

/* Every chip/gain pair: the driver clocks exactly 24 + g pulses (the chip
 * records them as the next gain) and decodes both full-scale ends. */
TEST(hx71x_read_every_gain_both_chips_full_scale)
{
    static const struct { uint8_t chip, gain, pulses; uint16_t rate; } cases[] = {
        { HX71X_CHIP_HX711, HX71X_GAIN_A_128, 25, 80 },
        { HX71X_CHIP_HX711, HX71X_GAIN_B_32, 26, 10 },
        { HX71X_CHIP_HX711, HX71X_GAIN_A_64, 27, 80 },
        { HX71X_CHIP_HX717, HX71X_GAIN_A_128, 25, 320 },
        { HX71X_CHIP_HX717, HX71X_GAIN_B_64, 26, 80 },
        { HX71X_CHIP_HX717, HX71X_GAIN_A_64, 27, 20 },
        { HX71X_CHIP_HX717, HX71X_GAIN_B_8, 28, 10 },
    };
    static const int32_t values[] = { 8388607, -8388608, 0, -1, 1, 0x5A5A5A, -3141592 };
    for (unsigned c = 0; c < sizeof(cases) / sizeof(cases[0]); c++) {
        struct rig rig;
        CHECK_EQ_INT(rig_setup(&rig, cases[c].chip, cases[c].gain, cases[c].rate, 0), HX71X_OK);
        rig_start_and_settle(&rig, unit_failed_);
        for (unsigned v = 0; v < sizeof(values) / sizeof(values[0]); v++) {
            int32_t counts = 42;
            CHECK_EQ_INT(rig_sample(&rig, values[v], &counts), HX71X_OK);
            CHECK_EQ_INT(counts, values[v]);
            CHECK_EQ_INT(rig.sim.pulses_seen, cases[c].pulses);
        }
        sim_hx71x_convert(&rig.sim, 0);
        CHECK_EQ_INT(rig.sim.last_frame_pulses, cases[c].pulses);
    }
}

TEST(hx71x_read_timing_and_interrupts)
{
    struct rig rig;
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX717, HX71X_GAIN_A_128, 320, 0), HX71X_OK);
    rig_start_and_settle(&rig, unit_failed_);
    rig.sim.reads_with_irq_on = 0;
    int32_t counts = 0;
    CHECK_EQ_INT(rig_sample(&rig, -77, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, -77);
    /* Datasheet: SCLK high 0.2..50 us, low at least 0.2 us. */
    CHECK(rig.sim.longest_high_ns >= 200 && rig.sim.longest_high_ns <= 50000);
    CHECK(rig.sim.shortest_low_ns >= 200);
    CHECK_EQ_INT(rig.sim.reads_with_irq_on, 0);
    CHECK_EQ_INT(rig.sim.irq_max_nesting, 1);
    CHECK_EQ_INT(rig.sim.irq_disabled, 0);
    CHECK_EQ_INT(rig.sim.power_cycles, 1);
}

TEST(hx71x_read_when_not_ready_clocks_nothing)
{
    struct rig rig;
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX711, HX71X_GAIN_A_128, 80, 0), HX71X_OK);
    rig_start_and_settle(&rig, unit_failed_);
    int32_t counts = 0;
    CHECK_EQ_INT(rig_sample(&rig, 10, &counts), HX71X_OK);
    CHECK_EQ_INT(hx71x_is_ready(&rig.dev), 0);
    CHECK_EQ_INT(hx71x_read(&rig.dev, rig.sim.now_ticks, &counts), HX71X_ERR_NOT_READY);
    CHECK_EQ_INT(rig.sim.pulses_seen, 25);
    /* Not sticky: the next conversion reads fine. */
    CHECK_EQ_INT(rig_sample(&rig, 11, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 11);
}

/* A noise-swallowed SCLK edge leaves the chip one bit behind: its LSB lands
 * in the first trailing slot. */
TEST(hx71x_missed_clock_edge_is_a_sticky_desync_until_restart)
{
    struct rig rig;
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX711, HX71X_GAIN_A_128, 80, 0), HX71X_OK);
    rig_start_and_settle(&rig, unit_failed_);
    int32_t counts = 0;
    rig.sim.missed_edges = 1;
    CHECK_EQ_INT(rig_sample(&rig, 0x000100, &counts), HX71X_ERR_DESYNC);
    CHECK_EQ_INT(counts, 0);
    /* Sticky: a good conversion is still refused, and not even clocked. */
    CHECK_EQ_INT(rig_sample(&rig, 500, &counts), HX71X_ERR_DESYNC);
    CHECK_EQ_INT(rig.sim.pulses_seen, 0);
    CHECK_EQ_INT(counts, 0);
    /* Restart clears it (after the settling samples). */
    rig_start_and_settle(&rig, unit_failed_);
    CHECK_EQ_INT(rig.sim.power_cycles, 2);
    CHECK_EQ_INT(rig_sample(&rig, 500, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 500);
}

TEST(hx71x_late_read_boundary_and_stickiness)
{
    /* 320 sps at 1 ns ticks: period 3125000 ticks. The frame takes
     * 25 pulses x 400 ns = 10000 ticks. Start near the 32-bit wrap so the
     * unsigned time arithmetic is exercised too. */
    struct rig rig;
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX717, HX71X_GAIN_A_128, 320, 0xFFFF0000u), HX71X_OK);
    CHECK_EQ_INT(rig.dev.sample_period_ticks, 3125000);
    rig_start_and_settle(&rig, unit_failed_);
    int32_t counts = 0;

    sim_hx71x_convert(&rig.sim, 123);
    uint32_t ready = rig.sim.now_ticks - (3125000u - 10000u - 1u); /* ends 1 tick early */
    CHECK_EQ_INT(hx71x_read(&rig.dev, ready, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 123);

    sim_hx71x_convert(&rig.sim, 456);
    ready = rig.sim.now_ticks - (3125000u - 10000u); /* ends exactly when the next is due */
    CHECK_EQ_INT(hx71x_read(&rig.dev, ready, &counts), HX71X_ERR_LATE_READ);
    CHECK_EQ_INT(counts, 123);
    CHECK_EQ_INT(rig_sample(&rig, 789, &counts), HX71X_ERR_LATE_READ);
    CHECK_EQ_INT(counts, 123);

    rig_start_and_settle(&rig, unit_failed_);
    CHECK_EQ_INT(rig_sample(&rig, 789, &counts), HX71X_OK);
    CHECK_EQ_INT(counts, 789);
}

TEST(hx71x_read_stretched_by_interrupts_is_late)
{
    /* The read starts on time, but each DOUT sample is delayed 130 us by
     * (simulated) interrupts: 25 x 130 us > 3.125 ms. */
    struct rig rig;
    CHECK_EQ_INT(rig_setup(&rig, HX71X_CHIP_HX717, HX71X_GAIN_A_128, 320, 0), HX71X_OK);
    rig_start_and_settle(&rig, unit_failed_);
    rig.sim.ticks_per_pin_read = 130000;
    int32_t counts = 0;
    CHECK_EQ_INT(rig_sample(&rig, 5, &counts), HX71X_ERR_LATE_READ);
    CHECK_EQ_INT(counts, 0);
}

TEST(hx71x_sample_period_is_the_exact_quotient)
{
    /* hx71x_init divides without the divide helper: check it against C's division. */
    static const uint32_t rates[] = {10, 20, 80, 320};
    static const uint32_t clocks[] = {320, 1000000, 12000000, 16000000, 125000000, 4294967295u};
    struct rig rig;
    sim_hx71x_init(&rig.sim, &rig.hal, SCLK_PIN, DOUT_PIN, 0);
    for (unsigned r = 0; r < sizeof rates / sizeof rates[0]; r++) {
        for (unsigned c = 0; c < sizeof clocks / sizeof clocks[0]; c++) {
            struct hx71x_config config = {
                .chip = HX71X_CHIP_HX717, .gain = HX71X_GAIN_A_128, .sample_rate_sps = (uint16_t)rates[r],
                .ticks_per_s = clocks[c], .sclk_pin = SCLK_PIN, .dout_pin = DOUT_PIN,
            };
            CHECK_EQ_INT(hx71x_init(&rig.dev, &rig.hal, &config), HX71X_OK);
            CHECK_EQ_INT(rig.dev.sample_period_ticks, clocks[c] / rates[r]);
        }
    }
}
