/* ADS1220: register computation for every option class, the start sequence
 * (reset check, write + readback, start) and the 24-bit read, against a
 * simulated chip. */
#include "unit.h"
#include "ads1220.h"
#include "sim_chips.h"

#define CS_PIN 9

static struct ads1220_config default_config(void)
{
    /* Spec defaults: gain 128, no bypass, 660 sps, AIN0_AIN1, internal ref. */
    return (struct ads1220_config){
        .gain = 128, .pga_bypass = 0, .sample_rate_sps = 660,
        .input_mux = ADS1220_MUX_AIN0_AIN1, .vref = ADS1220_VREF_INTERNAL,
    };
}

static enum ads1220_status regs_for(struct ads1220_config config, uint8_t regs[4])
{
    for (int i = 0; i < 4; i++)
        regs[i] = 0xEE;
    return ads1220_registers(&config, regs);
}

TEST(ads1220_default_registers)
{
    uint8_t regs[4];
    CHECK_EQ_INT(regs_for(default_config(), regs), ADS1220_OK);
    CHECK_EQ_INT(regs[0], 0x0E);   /* mux 0, gain code 7, PGA on */
    CHECK_EQ_INT(regs[1], 0x94);   /* DR 4, turbo (10), continuous */
    CHECK_EQ_INT(regs[2], 0x00);
    CHECK_EQ_INT(regs[3], 0x00);
}

TEST(ads1220_every_rate_in_both_modes)
{
    static const uint16_t normal[7] = { 20, 45, 90, 175, 330, 600, 1000 };
    static const uint16_t turbo[7] = { 40, 90, 180, 350, 660, 1200, 2000 };
    uint8_t regs[4];
    struct ads1220_config config = default_config();
    for (uint8_t dr = 0; dr < 7; dr++) {
        config.sample_rate_sps = normal[dr];
        CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
        CHECK_EQ_INT(regs[1], dr << 5 | 0x04);
        CHECK_EQ_INT(ads1220_rate_is_turbo(normal[dr]), 0);
        if (turbo[dr] == 90)
            continue; /* 90 resolves to normal mode, checked below */
        config.sample_rate_sps = turbo[dr];
        CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
        CHECK_EQ_INT(regs[1], dr << 5 | 0x10 | 0x04);
        CHECK_EQ_INT(ads1220_rate_is_turbo(turbo[dr]), 1);
    }
    /* 90 sps: normal mode, DR = 2 (0x44), not turbo DR = 1 (0x34). */
    config.sample_rate_sps = 90;
    CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
    CHECK_EQ_INT(regs[1], 0x44);
}

TEST(ads1220_rejects_rates_outside_the_lists)
{
    static const uint16_t bad[] = { 0, 10, 21, 80, 100, 320, 500, 999, 1001, 2001, 4000, 65535 };
    uint8_t regs[4];
    struct ads1220_config config = default_config();
    for (unsigned i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
        config.sample_rate_sps = bad[i];
        CHECK_EQ_INT(regs_for(config, regs), ADS1220_ERR_BAD_SAMPLE_RATE);
        CHECK_EQ_INT(ads1220_rate_is_turbo(bad[i]), 0);
    }
    CHECK_EQ_INT(regs[1], 0xEE); /* nothing written on error */
}

TEST(ads1220_every_gain_with_and_without_bypass)
{
    uint8_t regs[4];
    struct ads1220_config config = default_config();
    for (uint8_t code = 0; code < 8; code++) {
        config.gain = (uint8_t)(1u << code);
        config.pga_bypass = 0;
        CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
        CHECK_EQ_INT(regs[0], code << 1);
        /* Bypass takes effect for gains 1, 2, 4; for 8..128 the PGA is
         * always on, so the bit stays clear. */
        config.pga_bypass = 1;
        CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
        CHECK_EQ_INT(regs[0], code << 1 | (code <= 2 ? 1 : 0));
    }
    static const uint8_t bad_gains[] = { 0, 3, 5, 6, 7, 9, 12, 100, 127, 129, 255 };
    for (unsigned i = 0; i < sizeof(bad_gains); i++) {
        config.gain = bad_gains[i];
        CHECK_EQ_INT(regs_for(config, regs), ADS1220_ERR_BAD_GAIN);
    }
}

TEST(ads1220_every_mux_code_and_avss_forces_bypass)
{
    uint8_t regs[4];
    struct ads1220_config config = default_config();
    for (uint8_t mux = 0; mux < 8; mux++) {
        config.input_mux = mux;
        config.gain = 4;
        CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
        CHECK_EQ_INT(regs[0], mux << 4 | 2 << 1);
    }
    for (uint8_t mux = ADS1220_MUX_AIN0_AVSS; mux <= ADS1220_MUX_AIN3_AVSS; mux++) {
        config.input_mux = mux;
        config.pga_bypass = 0;
        for (uint8_t code = 0; code <= 2; code++) {
            config.gain = (uint8_t)(1u << code);
            CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
            CHECK_EQ_INT(regs[0], mux << 4 | code << 1 | 1);
        }
        for (uint8_t code = 3; code < 8; code++) {
            config.gain = (uint8_t)(1u << code);
            CHECK_EQ_INT(regs_for(config, regs), ADS1220_ERR_AVSS_NEEDS_LOW_GAIN);
        }
    }
    config.gain = 1;
    config.input_mux = 12;
    CHECK_EQ_INT(regs_for(config, regs), ADS1220_ERR_BAD_INPUT_MUX);
    config.input_mux = 255;
    CHECK_EQ_INT(regs_for(config, regs), ADS1220_ERR_BAD_INPUT_MUX);
}

TEST(ads1220_vref_codes_and_ref1_pin_conflict)
{
    uint8_t regs[4];
    struct ads1220_config config = default_config();
    config.input_mux = ADS1220_MUX_AIN1_AIN2; /* the one differential pair free of AIN0/AIN3 */
    for (uint8_t vref = 0; vref < 4; vref++) {
        config.vref = vref;
        CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
        CHECK_EQ_INT(regs[2], vref << 6);
    }
    config.vref = 4;
    CHECK_EQ_INT(regs_for(config, regs), ADS1220_ERR_BAD_VREF);

    /* REF1 is allowed only with AIN1_AIN2, AIN1_AVSS and AIN2_AVSS. */
    config.vref = ADS1220_VREF_REF1;
    config.gain = 1;
    for (uint8_t mux = 0; mux < 12; mux++) {
        config.input_mux = mux;
        int free_of_ain0_ain3 = mux == ADS1220_MUX_AIN1_AIN2 || mux == ADS1220_MUX_AIN1_AVSS
            || mux == ADS1220_MUX_AIN2_AVSS;
        CHECK_EQ_INT(regs_for(config, regs),
                     free_of_ain0_ain3 ? ADS1220_OK : ADS1220_ERR_REF1_PIN_CONFLICT);
    }
    /* The other references are fine with AIN0/AIN3. */
    config.input_mux = ADS1220_MUX_AIN0_AIN3;
    config.vref = ADS1220_VREF_REF0;
    CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
    CHECK_EQ_INT(regs[0], 0x20);
    CHECK_EQ_INT(regs[2], 0x40);
}

TEST(ads1220_combined_register_example)
{
    /* gain 2, AIN2_AVSS (bypass forced), 1200 sps turbo, analog supply ref. */
    uint8_t regs[4];
    struct ads1220_config config = {
        .gain = 2, .pga_bypass = 0, .sample_rate_sps = 1200,
        .input_mux = ADS1220_MUX_AIN2_AVSS, .vref = ADS1220_VREF_ANALOG_SUPPLY,
    };
    CHECK_EQ_INT(regs_for(config, regs), ADS1220_OK);
    CHECK_EQ_INT(regs[0], 0xA3);
    CHECK_EQ_INT(regs[1], 0xB4);
    CHECK_EQ_INT(regs[2], 0xC0);
    CHECK_EQ_INT(regs[3], 0x00);
}

struct ads_rig {
    struct sim_ads1220 sim;
    struct tc_hal hal;
    struct ads1220 dev;
};

static enum ads1220_status ads_rig_setup(struct ads_rig *rig, struct ads1220_config config)
{
    sim_ads1220_init(&rig->sim, &rig->hal, CS_PIN);
    return ads1220_init(&rig->dev, &rig->hal, CS_PIN, &config);
}

TEST(ads1220_start_writes_and_verifies_registers)
{
    struct ads_rig rig;
    struct ads1220_config config = default_config();
    config.sample_rate_sps = 2000;
    CHECK_EQ_INT(ads_rig_setup(&rig, config), ADS1220_OK);
    /* Leftover state from before the reset must not matter. */
    rig.sim.registers[0] = 0x55;
    int32_t counts = 0;
    CHECK_EQ_INT(ads1220_read(&rig.dev, &counts), ADS1220_ERR_NOT_STARTED);
    CHECK_EQ_INT(ads1220_start(&rig.dev), ADS1220_OK);
    CHECK_EQ_INT(rig.sim.resets, 1);
    CHECK_EQ_INT(rig.sim.started, 1);
    CHECK_EQ_INT(rig.sim.registers[0], 0x0E);
    CHECK_EQ_INT(rig.sim.registers[1], 0xD4);
    CHECK_EQ_INT(rig.sim.registers[2], 0x00);
    CHECK_EQ_INT(rig.sim.registers[3], 0x00);
    CHECK_EQ_INT(rig.sim.protocol_errors, 0);
    CHECK_EQ_INT(rig.sim.command_too_soon, 0);
    CHECK_EQ_INT(rig.sim.cs, 1);
}

TEST(ads1220_read_24_bit_sign_extended)
{
    static const int32_t values[] = { 8388607, -8388608, 0, -1, 1, 0x123456, -0x123456 };
    struct ads_rig rig;
    CHECK_EQ_INT(ads_rig_setup(&rig, default_config()), ADS1220_OK);
    CHECK_EQ_INT(ads1220_start(&rig.dev), ADS1220_OK);
    for (unsigned i = 0; i < sizeof(values) / sizeof(values[0]); i++) {
        int32_t counts = 42;
        rig.sim.conversion = values[i];
        CHECK_EQ_INT(ads1220_read(&rig.dev, &counts), ADS1220_OK);
        CHECK_EQ_INT(counts, values[i]);
    }
    CHECK_EQ_INT(rig.sim.protocol_errors, 0);
}

TEST(ads1220_reset_state_check_is_sticky_until_a_good_start)
{
    struct ads_rig rig;
    CHECK_EQ_INT(ads_rig_setup(&rig, default_config()), ADS1220_OK);
    rig.sim.reset_state[2] = 0x10; /* chip did not really reset */
    CHECK_EQ_INT(ads1220_start(&rig.dev), ADS1220_ERR_RESET_STATE);
    CHECK_EQ_INT(rig.dev.registers_read[2], 0x10);
    CHECK_EQ_INT(rig.sim.started, 0);
    CHECK_EQ_INT(rig.sim.registers[0], 0x00); /* nothing written */
    int32_t counts = 7;
    rig.sim.conversion = 1000;
    CHECK_EQ_INT(ads1220_read(&rig.dev, &counts), ADS1220_ERR_RESET_STATE);
    CHECK_EQ_INT(counts, 7);
    rig.sim.reset_state[2] = 0;
    CHECK_EQ_INT(ads1220_start(&rig.dev), ADS1220_OK);
    CHECK_EQ_INT(ads1220_read(&rig.dev, &counts), ADS1220_OK);
    CHECK_EQ_INT(counts, 1000);
}

TEST(ads1220_readback_mismatch_is_reported_and_not_started)
{
    struct ads_rig rig;
    CHECK_EQ_INT(ads_rig_setup(&rig, default_config()), ADS1220_OK);
    /* reg0 should be 0x0E; a gain bit that cannot be set reads back 0x0A.
     * Reset reads 0 either way, so only the readback can catch it. */
    rig.sim.stuck_low[0] = 0x04;
    CHECK_EQ_INT(ads1220_start(&rig.dev), ADS1220_ERR_READBACK_MISMATCH);
    CHECK_EQ_INT(rig.dev.registers_read[0], 0x0A);
    CHECK_EQ_INT(rig.sim.started, 0);
    int32_t counts = 3;
    CHECK_EQ_INT(ads1220_read(&rig.dev, &counts), ADS1220_ERR_READBACK_MISMATCH);
    CHECK_EQ_INT(counts, 3);
    CHECK_EQ_INT(rig.sim.protocol_errors, 0);
}

TEST(ads1220_dead_bus_fails_the_reset_check)
{
    /* MISO floating high: every register reads 0xFF. */
    struct ads_rig rig;
    CHECK_EQ_INT(ads_rig_setup(&rig, default_config()), ADS1220_OK);
    for (int i = 0; i < 4; i++)
        rig.sim.reset_state[i] = 0xFF;
    CHECK_EQ_INT(ads1220_start(&rig.dev), ADS1220_ERR_RESET_STATE);
    CHECK_EQ_INT(rig.sim.started, 0);
}

TEST(ads1220_init_rejects_bad_config)
{
    struct ads_rig rig;
    struct ads1220_config config = default_config();
    config.input_mux = ADS1220_MUX_AIN3_AVSS; /* gain 128 cannot bypass the PGA */
    CHECK_EQ_INT(ads_rig_setup(&rig, config), ADS1220_ERR_AVSS_NEEDS_LOW_GAIN);
    config = default_config();
    config.vref = ADS1220_VREF_REF1;
    CHECK_EQ_INT(ads_rig_setup(&rig, config), ADS1220_ERR_REF1_PIN_CONFLICT);
}
