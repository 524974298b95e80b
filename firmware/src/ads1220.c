/* ads1220.c - ADS1220 register computation, start-up checks and data read
 * through the HAL. See ads1220.h. No allocation, no floats, no globals. */
#include "ads1220.h"

#define RATE_COUNT 7u
#define MODE_NORMAL 0u
#define MODE_TURBO 2u
#define CONTINUOUS_CONVERSION 0x04u /* reg1 CM bit */

/* DR[2:0] is the position in these lists. Turbo runs the modulator twice as
 * fast, doubling each normal rate; that is why 90 is in both lists (normal
 * DR=2, and turbo DR=1 as the doubled 45). */
static const uint16_t normal_rates_sps[RATE_COUNT] = { 20, 45, 90, 175, 330, 600, 1000 };
static const uint16_t turbo_rates_sps[RATE_COUNT] = { 40, 90, 180, 350, 660, 1200, 2000 };

/* Index of `rate` in `rates`, or RATE_COUNT when absent. */
static uint8_t rate_index(const uint16_t rates[RATE_COUNT], uint16_t rate)
{
    uint8_t i = 0;
    while (i < RATE_COUNT && rates[i] != rate)
        i++;
    return i;
}

uint8_t ads1220_rate_is_turbo(uint16_t sample_rate_sps)
{
    /* The normal list is searched first, so 90 sps (in both) is normal mode. */
    return rate_index(normal_rates_sps, sample_rate_sps) == RATE_COUNT
        && rate_index(turbo_rates_sps, sample_rate_sps) < RATE_COUNT;
}

/* log2(gain) for gains 1..128, or -1 when not a power of two in range. */
static int8_t gain_code(uint8_t gain)
{
    for (int8_t code = 0; code < 8; code++) {
        if (gain == (1u << code))
            return code;
    }
    return -1;
}

static uint8_t mux_uses_ain0_or_ain3(uint8_t mux)
{
    /* Pins per mux code (bit n = AINn) from the datasheet's MUX table. */
    static const uint8_t pins_used[12] = {
        0x3, 0x5, 0x9, 0x6, 0xA, 0xC, 0x3, 0xC, 0x1, 0x2, 0x4, 0x8
    };
    return (pins_used[mux] & 0x9u) != 0;
}

static uint8_t mux_uses_avss(uint8_t mux)
{
    return mux >= ADS1220_MUX_AIN0_AVSS;
}

uint8_t ads1220_pga_bypassed(uint8_t gain, uint8_t pga_bypass, uint8_t input_mux)
{
    /* Single-ended inputs sit outside the PGA's common-mode range, so AVSS
     * forces the bypass. For gains 8..128 the PGA is always on whatever the
     * bit says, so the bit is set only where it has an effect. */
    return (pga_bypass || mux_uses_avss(input_mux)) && gain <= 4;
}

enum ads1220_status ads1220_registers(const struct ads1220_config *config,
                                      uint8_t registers[ADS1220_REGISTER_COUNT])
{
    int8_t gain_bits = gain_code(config->gain);
    if (gain_bits < 0)
        return ADS1220_ERR_BAD_GAIN;
    if (config->input_mux > ADS1220_MUX_AIN3_AVSS)
        return ADS1220_ERR_BAD_INPUT_MUX;
    if (config->vref > ADS1220_VREF_ANALOG_SUPPLY)
        return ADS1220_ERR_BAD_VREF;

    uint8_t mode = MODE_NORMAL;
    uint8_t data_rate = rate_index(normal_rates_sps, config->sample_rate_sps);
    if (data_rate == RATE_COUNT) {
        mode = MODE_TURBO;
        data_rate = rate_index(turbo_rates_sps, config->sample_rate_sps);
        if (data_rate == RATE_COUNT)
            return ADS1220_ERR_BAD_SAMPLE_RATE;
    }

    /* REFP1/REFN1 are the AIN0/AIN3 pins: they cannot be reference and input. */
    if (config->vref == ADS1220_VREF_REF1 && mux_uses_ain0_or_ain3(config->input_mux))
        return ADS1220_ERR_REF1_PIN_CONFLICT;

    /* Single-ended inputs (negative side AVSS) need the PGA bypassed, which
     * the chip can only do for gains 1, 2 and 4. */
    if (mux_uses_avss(config->input_mux) && config->gain > 4)
        return ADS1220_ERR_AVSS_NEEDS_LOW_GAIN;
    uint8_t pga_bypass =
        ads1220_pga_bypassed(config->gain, config->pga_bypass, config->input_mux);

    registers[0] = (uint8_t)(config->input_mux << 4 | (uint8_t)gain_bits << 1 | pga_bypass);
    registers[1] = (uint8_t)(data_rate << 5 | mode << 3 | CONTINUOUS_CONVERSION);
    registers[2] = (uint8_t)(config->vref << 6);
    registers[3] = 0;
    return ADS1220_OK;
}

enum ads1220_status ads1220_init(struct ads1220 *dev, const struct tc_hal *hal,
                                 uint16_t cs_pin, const struct ads1220_config *config)
{
    enum ads1220_status status = ads1220_registers(config, dev->registers);
    if (status != ADS1220_OK)
        return status;
    dev->hal = hal;
    dev->cs_pin = cs_pin;
    for (uint8_t i = 0; i < ADS1220_REGISTER_COUNT; i++)
        dev->registers_read[i] = 0;
    dev->error = ADS1220_ERR_NOT_STARTED;
    return ADS1220_OK;
}

/* One command = one chip-select window. */
static void spi_command(const struct ads1220 *dev, uint8_t *data, uint8_t len)
{
    const struct tc_hal *hal = dev->hal;
    hal->pin_write(hal->ctx, dev->cs_pin, 0);
    hal->spi_transfer(hal->ctx, data, len);
    hal->pin_write(hal->ctx, dev->cs_pin, 1);
}

static void read_all_registers(struct ads1220 *dev)
{
    uint8_t frame[1 + ADS1220_REGISTER_COUNT] = {
        ADS1220_CMD_RREG | (ADS1220_REGISTER_COUNT - 1u), 0, 0, 0, 0
    };
    spi_command(dev, frame, sizeof(frame));
    for (uint8_t i = 0; i < ADS1220_REGISTER_COUNT; i++)
        dev->registers_read[i] = frame[1 + i];
}

static uint8_t registers_read_equal(const struct ads1220 *dev, const uint8_t expected[])
{
    for (uint8_t i = 0; i < ADS1220_REGISTER_COUNT; i++) {
        if (dev->registers_read[i] != expected[i])
            return 0;
    }
    return 1;
}

enum ads1220_status ads1220_start(struct ads1220 *dev)
{
    static const uint8_t reset_state[ADS1220_REGISTER_COUNT] = { 0, 0, 0, 0 };

    uint8_t reset_cmd = ADS1220_CMD_RESET;
    spi_command(dev, &reset_cmd, 1);
    dev->hal->delay_ns(dev->hal->ctx, ADS1220_RESET_WAIT_NS);

    read_all_registers(dev);
    if (!registers_read_equal(dev, reset_state)) {
        dev->error = ADS1220_ERR_RESET_STATE;
        return dev->error;
    }

    uint8_t write_frame[1 + ADS1220_REGISTER_COUNT];
    write_frame[0] = ADS1220_CMD_WREG | (ADS1220_REGISTER_COUNT - 1u);
    for (uint8_t i = 0; i < ADS1220_REGISTER_COUNT; i++)
        write_frame[1 + i] = dev->registers[i];
    spi_command(dev, write_frame, sizeof(write_frame));

    read_all_registers(dev);
    if (!registers_read_equal(dev, dev->registers)) {
        dev->error = ADS1220_ERR_READBACK_MISMATCH;
        return dev->error;
    }

    uint8_t start_cmd = ADS1220_CMD_START;
    spi_command(dev, &start_cmd, 1);
    dev->error = ADS1220_OK;
    return ADS1220_OK;
}

enum ads1220_status ads1220_read(struct ads1220 *dev, int32_t *counts)
{
    if (dev->error != ADS1220_OK)
        return dev->error;
    /* In continuous mode the result is clocked out directly after DRDY,
     * with DIN held low (0x00 is not a command). */
    uint8_t frame[3] = { 0, 0, 0 };
    spi_command(dev, frame, sizeof(frame));
    uint32_t word = (uint32_t)frame[0] << 16 | (uint32_t)frame[1] << 8 | frame[2];
    *counts = tc_sign_extend_24(word);
    return ADS1220_OK;
}
