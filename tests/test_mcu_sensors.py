"""tapcell.mcu.sensors: sensor tables, and the firmware's HX71x / ADS1220 code through cffi."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from tapcell.mcu import sensors
from tapcell.mcu.sensors import SensorConfigError, SensorFrameError

# ---------------------------------------------------------------------------
# Tables


def test_sample_rate_tables():
    assert sensors.SAMPLE_RATES_SPS["hx711"] == (10, 80)
    assert sensors.SAMPLE_RATES_SPS["hx717"] == (10, 20, 80, 320)
    assert sensors.SAMPLE_RATES_SPS["ads1220"] == (
        20, 40, 45, 90, 175, 180, 330, 350, 600, 660, 1000, 1200, 2000)
    assert sensors.DEFAULT_SAMPLE_RATE_SPS == {"hx711": 80, "hx717": 320, "ads1220": 660}


def test_hx71x_rate_table_agrees_with_firmware():
    _, lib = sensors._firmware()
    for chip_code, chip in enumerate(sensors.HX71X_CHIPS):
        accepted = tuple(rate for rate in range(0, 2001)
                         if lib.hx71x_check_sample_rate(chip_code, rate) == 0)
        assert accepted == sensors.SAMPLE_RATES_SPS[chip]


def test_ads1220_rate_table_agrees_with_firmware():
    ffi, lib = sensors._firmware()
    registers = ffi.new("uint8_t[4]")
    accepted = []
    for rate in range(0, 2201):
        config = ffi.new("struct ads1220_config *", {"gain": 1, "sample_rate_sps": rate})
        if lib.ads1220_registers(config, registers) == 0:
            accepted.append(rate)
    assert tuple(accepted) == sensors.SAMPLE_RATES_SPS["ads1220"]


# ---------------------------------------------------------------------------
# HX711 / HX717


@pytest.mark.parametrize("chip, gain, pulses", [
    ("hx711", "A-128", 25), ("hx711", "B-32", 26), ("hx711", "A-64", 27),
    ("hx717", "A-128", 25), ("hx717", "B-64", 26), ("hx717", "A-64", 27), ("hx717", "B-8", 28),
])
def test_hx71x_pulses(chip, gain, pulses):
    assert sensors.hx71x_pulses(chip, gain) == pulses


def test_hx71x_gain_table_lists_exactly_what_the_chip_accepts():
    all_names = {"A-128", "B-32", "A-64", "B-64", "B-8"}
    for chip in sensors.HX71X_CHIPS:
        for name in all_names - set(sensors.HX71X_GAINS[chip]):
            with pytest.raises(SensorConfigError):
                sensors.hx71x_pulses(chip, name)


def test_hx71x_bad_gain_names_option_value_and_allowed():
    with pytest.raises(SensorConfigError) as excinfo:
        sensors.hx71x_pulses("hx711", "B-8")
    assert (excinfo.value.option, excinfo.value.value) == ("gain", "B-8")
    assert str(excinfo.value) == "gain = B-8 is not allowed; allowed: A-128, B-32, A-64"
    with pytest.raises(SensorConfigError) as excinfo:
        sensors.hx71x_pulses("hx717", "a-128")
    assert str(excinfo.value) == "gain = a-128 is not allowed; allowed: A-128, B-64, A-64, B-8"


def test_hx71x_bad_chip():
    with pytest.raises(SensorConfigError) as excinfo:
        sensors.hx71x_pulses("hx712", "A-128")
    assert str(excinfo.value) == "sensor_type = hx712 is not allowed; allowed: hx711, hx717"


def test_hx71x_check_sample_rate():
    assert sensors.hx71x_check_sample_rate("hx717", 320) == 320
    assert sensors.hx71x_check_sample_rate("hx711", 80.0) == 80
    with pytest.raises(SensorConfigError) as excinfo:
        sensors.hx71x_check_sample_rate("hx711", 320)
    assert str(excinfo.value) == "sample_rate = 320 is not allowed; allowed: 10, 80"
    with pytest.raises(SensorConfigError):
        sensors.hx71x_check_sample_rate("hx717", True)


def test_decode_raw_words_full_scale_and_shape():
    words = np.array([[0x7FFFFF, 0x800000, 0xFFFFFF], [0, 1, 0x123456]], dtype=np.uint32)
    counts = sensors.decode_hx71x_frames(words)
    assert counts.dtype == np.int32
    assert counts.shape == (2, 3)
    assert counts.tolist() == [[8388607, -8388608, -1], [0, 1, 0x123456]]


def test_decode_ten_thousand_words_matches_numpy_sign_extension():
    rng = np.random.default_rng(7)
    words = rng.integers(0, 1 << 24, size=10_000, dtype=np.uint32)
    expected = np.where(words >= 1 << 23, words.astype(np.int64) - (1 << 24), words)
    np.testing.assert_array_equal(sensors.decode_hx71x_frames(words), expected)


@pytest.mark.parametrize("pulses", [25, 26, 27, 28])
def test_decode_whole_frames(pulses):
    trailing = pulses - 24
    values = np.array([-8388608, -5, 0, 77, 8388607])
    frames = ((values & 0xFFFFFF) << trailing) | ((1 << trailing) - 1)
    np.testing.assert_array_equal(sensors.decode_hx71x_frames(frames, pulses=pulses), values)


def test_decode_desync_names_the_frame():
    frames = np.array([0x3 | 10 << 2, 0x3 | 20 << 2, 0x2 | 30 << 2, 0x0], dtype=np.uint32)
    with pytest.raises(SensorFrameError) as excinfo:
        sensors.decode_hx71x_frames(frames, pulses=26)
    assert excinfo.value.index == 2
    assert str(excinfo.value) == "frame 2 (0x7a): trailing bits 0b10 must all be 1 (desync)"


def test_decode_rejects_words_wider_than_the_frame():
    with pytest.raises(SensorFrameError) as excinfo:
        sensors.decode_hx71x_frames(np.array([5, 1 << 24], dtype=np.int64))
    assert str(excinfo.value) == "frame 1 (0x1000000): does not fit in a 24-bit frame"
    with pytest.raises(SensorFrameError) as excinfo:
        sensors.decode_hx71x_frames([3, -1])
    assert excinfo.value.index == 1


def test_decode_rejects_bad_pulses_and_float_frames():
    with pytest.raises(SensorConfigError) as excinfo:
        sensors.decode_hx71x_frames([1], pulses=29)
    assert str(excinfo.value) == "pulses = 29 is not allowed; allowed: 24, 25, 26, 27, 28"
    with pytest.raises(TypeError, match="integer array"):
        sensors.decode_hx71x_frames(np.array([1.0]))


def test_decode_empty_batch():
    assert sensors.decode_hx71x_frames(np.array([], dtype=np.uint32)).shape == (0,)


# ---------------------------------------------------------------------------
# ADS1220


def test_ads1220_default_registers():
    assert sensors.ads1220_registers(128, False, 660, "AIN0_AIN1", "internal") == bytes([0x0E, 0x94, 0x00, 0x00])


def test_ads1220_90_sps_is_normal_mode():
    registers = sensors.ads1220_registers(128, False, 90, "AIN0_AIN1", "internal")
    assert registers[1] == 0x44  # DR=2, normal, continuous (turbo DR=1 would be 0x34)
    assert sensors.ads1220_is_turbo(90) is False
    assert sensors.ads1220_spi_speed_hz(90) == 256000


def test_ads1220_turbo_and_spi_speed():
    assert [sensors.ads1220_is_turbo(r) for r in sensors.ADS1220_TURBO_SAMPLE_RATES_SPS] == [
        True, False, True, True, True, True, True]
    assert not any(sensors.ads1220_is_turbo(r) for r in sensors.ADS1220_NORMAL_SAMPLE_RATES_SPS)
    assert sensors.ads1220_spi_speed_hz(660) == 512000
    assert sensors.ads1220_spi_speed_hz(1000) == 256000


def _datasheet_registers(gain, pga_bypass, rate, mux, vref):
    """Independent reference: the datasheet's bit layout, written out by hand."""
    mux_code = sensors.ADS1220_INPUT_MUXES.index(mux)
    if rate in sensors.ADS1220_NORMAL_SAMPLE_RATES_SPS:
        data_rate, mode = sensors.ADS1220_NORMAL_SAMPLE_RATES_SPS.index(rate), 0
    else:
        data_rate, mode = sensors.ADS1220_TURBO_SAMPLE_RATES_SPS.index(rate), 2
    bypass = int((pga_bypass or mux.endswith("AVSS")) and gain <= 4)
    return bytes([
        mux_code << 4 | gain.bit_length() - 1 << 1 | bypass,
        data_rate << 5 | mode << 3 | 0x04,
        sensors.ADS1220_VREFS.index(vref) << 6,
        0,
    ])


def test_ads1220_every_combination_matches_the_datasheet_layout():
    checked = refused = 0
    for gain, bypass, rate, mux, vref in itertools.product(
            sensors.ADS1220_GAINS, (False, True), sensors.SAMPLE_RATES_SPS["ads1220"],
            sensors.ADS1220_INPUT_MUXES, sensors.ADS1220_VREFS):
        ref1_conflict = vref == "REF1" and ("AIN0" in mux or "AIN3" in mux)
        avss_high_gain = mux.endswith("AVSS") and gain > 4
        if ref1_conflict or avss_high_gain:
            with pytest.raises(SensorConfigError):
                sensors.ads1220_registers(gain, bypass, rate, mux, vref)
            refused += 1
            continue
        assert sensors.ads1220_registers(gain, bypass, rate, mux, vref) == \
            _datasheet_registers(gain, bypass, rate, mux, vref)
        checked += 1
    assert (checked, refused) == (6292, 3692)


def test_ads1220_ref1_conflict_message():
    with pytest.raises(SensorConfigError) as excinfo:
        sensors.ads1220_registers(128, False, 660, "AIN0_AIN1", "REF1")
    assert (excinfo.value.option, excinfo.value.value) == ("vref", "REF1")
    assert str(excinfo.value) == (
        "vref = REF1 is not allowed; allowed: internal, REF0, analog_supply with input_mux AIN0_AIN1 "
        "(REF1 shares its pins with AIN0 and AIN3; it works only with AIN1_AIN2, AIN1_AVSS, AIN2_AVSS)")
    assert sensors.ads1220_registers(128, False, 660, "AIN1_AIN2", "REF1") == bytes([0x3E, 0x94, 0x80, 0])


def test_ads1220_avss_needs_low_gain_message():
    with pytest.raises(SensorConfigError) as excinfo:
        sensors.ads1220_registers(128, False, 660, "AIN0_AVSS", "internal")
    assert (excinfo.value.option, excinfo.value.value) == ("gain", 128)
    assert str(excinfo.value) == (
        "gain = 128 is not allowed; allowed: 1, 2, 4 with input_mux AIN0_AVSS "
        "(an AVSS input needs the PGA bypassed, which the chip can only do up to gain 4)")
    assert sensors.ads1220_registers(4, False, 660, "AIN0_AVSS", "internal") == bytes([0x85, 0x94, 0, 0])


@pytest.mark.parametrize("args, option, allowed", [
    ((3, False, 660, "AIN0_AIN1", "internal"), "gain", "1, 2, 4, 8, 16, 32, 64, 128"),
    ((True, False, 660, "AIN0_AIN1", "internal"), "gain", "1, 2, 4, 8, 16, 32, 64, 128"),
    ((128, False, 100, "AIN0_AIN1", "internal"), "sample_rate",
     "normal 20, 45, 90, 175, 330, 600, 1000; turbo 40, 90, 180, 350, 660, 1200, 2000"),
    ((128, False, 660, "AIN0-AIN1", "internal"), "input_mux",
     "AIN0_AIN1, AIN0_AIN2, AIN0_AIN3, AIN1_AIN2, AIN1_AIN3, AIN2_AIN3, AIN1_AIN0, AIN3_AIN2, "
     "AIN0_AVSS, AIN1_AVSS, AIN2_AVSS, AIN3_AVSS"),
    ((128, False, 660, "AIN0_AIN1", "external"), "vref", "internal, REF0, REF1, analog_supply"),
])
def test_ads1220_single_bad_values(args, option, allowed):
    with pytest.raises(SensorConfigError) as excinfo:
        sensors.ads1220_registers(*args)
    assert excinfo.value.option == option
    assert excinfo.value.allowed == allowed


def test_ads1220_effective_pga_bypass():
    assert sensors.ads1220_effective_pga_bypass(4, True, "AIN0_AIN1") is True
    assert sensors.ads1220_effective_pga_bypass(8, True, "AIN0_AIN1") is False
    assert sensors.ads1220_effective_pga_bypass(1, False, "AIN2_AVSS") is True
    assert sensors.ads1220_effective_pga_bypass(2, False, "AIN1_AIN3") is False


# ---------------------------------------------------------------------------
# Noise floor and the stuck-sensor run length


def test_noise_floor_from_the_datasheets():
    # HX711: 50 nV RMS at 10 sps and 90 nV at 80 sps (gain 128); a count is 5.5 V / gain / 2^24 at most
    assert sensors.noise_floor_counts("hx711", "A-128", 10) == pytest.approx(19.52, abs=0.01)
    assert sensors.noise_floor_counts("hx711", "A-128", 80) == pytest.approx(35.14, abs=0.01)
    assert sensors.noise_floor_counts("hx711", "B-32", 80) == pytest.approx(35.14 / 4, abs=0.01)
    assert sensors.noise_floor_counts("hx717", "B-8", 20) == pytest.approx(19.52 / 16, abs=0.01)
    # ADS1220: at most 20 effective bits of 24, in every mode
    assert sensors.noise_floor_counts("ads1220", "1", 20) == sensors.noise_floor_counts("ads1220", "128", 2000) == 16
    with pytest.raises(SensorConfigError, match="gain = B-8 is not allowed; allowed: A-128, B-32, A-64"):
        sensors.noise_floor_counts("hx711", "B-8", 80)


def test_run_probability_never_underestimates_rounded_gaussian_noise():
    # Measured on numpy's noise, not derived from the formula: runs of n equal rounded readings.
    # The formula may be high (a longer default run: safe), never low; measured within 1..12 %.
    rng = np.random.default_rng(11)
    for sigma, n in ((1.2, 2), (1.2, 3), (1.2, 5), (2.2, 3), (4.0, 3), (8.0, 2)):
        readings = np.round(rng.normal(1000.3, sigma, 2_000_000))
        same = np.ones(readings.size - n + 1, dtype=bool)
        for k in range(1, n):
            same &= readings[k:readings.size - n + 1 + k] == readings[:readings.size - n + 1]
        model = sensors.identical_run_probability(sigma, n)
        assert 0.85 * model <= same.mean() <= 1.02 * model, (sigma, n)


@pytest.mark.parametrize("chip, gain, rate, samples", [
    ("hx717", "A-128", 320, 7), ("hx711", "A-128", 80, 7), ("hx711", "A-128", 10, 7), ("hx711", "B-32", 80, 10),
    ("hx717", "B-8", 320, 17), ("hx717", "B-8", 10, 22), ("ads1220", "128", 660, 9), ("ads1220", "1", 20, 8),
])
def test_default_stuck_runs(chip, gain, rate, samples):
    noise = sensors.noise_floor_counts(chip, gain, rate)
    assert sensors.stuck_sample_count(noise, rate, 65535) == samples
    # the run one shorter would be seen more often than once per million armed hours
    per_hour = 3600 * rate
    assert sensors.identical_run_probability(noise, samples) * per_hour <= 1e-6
    assert sensors.identical_run_probability(noise, samples - 1) * per_hour > 1e-6
