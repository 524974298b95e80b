"""ADS131M02/M04: the rate choice, the firmware's register words and frame reader through cffi,
the [load_cell] options, the virtual chip's CRC-checked frames, and probing on one."""

from __future__ import annotations

import numpy as np
import pytest

from machines import machine_config
from tapcell.host.config import ConfigError
from tapcell.host.gcode import GCodeError
from tapcell.host.printer import Printer
from tapcell.mcu import ads131m0x
from tapcell.mcu.sensors import SensorConfigError
from tapcell.sim.printer import VirtualPrinter

CELL = """
[load_cell_probe]
sensor_type: {chip}
cs_pin: PA4
data_ready_pin: PA5
spi_bus: spi1
{clock}
z_offset: 0
counts_per_gram: 110
reference_tare_counts: -38000
pullback_distance: 0.15
"""


def printer_with(tmp_path, chip="ads131m02", clock="clock_freq: 8192000", extra="", world=""):
    machine = machine_config().replace("seed: 1\n", "seed: 1\n" + world)
    (tmp_path / "printer.cfg").write_text(machine + CELL.format(chip=chip, clock=clock) + extra)
    responses: list[str] = []
    return Printer.from_config(str(tmp_path / "printer.cfg"), responses=responses.append), responses


def config_error(tmp_path, **kwargs) -> str:
    with pytest.raises(ConfigError) as info:
        printer_with(tmp_path, **kwargs)
    return str(info.value)


def test_the_rate_is_the_closest_osr_at_the_clock():
    assert ads131m0x.choose_osr(8_192_000, 500) == (8192, 500.0)
    assert ads131m0x.choose_osr(8_192_000, 800) == (4096, 1000.0)  # |1000-800| < |500-800|
    assert ads131m0x.choose_osr(8_192_000, 700) == (8192, 500.0)
    assert ads131m0x.choose_osr(8_192_000, 64000) == (64, 64000.0)
    # Global chop adds its delay to three conversions: 8192000 / (2 (16 + 3 x 4096)) = 333.0 sps
    osr, rate = ads131m0x.choose_osr(8_192_000, 330, chop_delay=16)
    assert osr == 4096 and rate == pytest.approx(8_192_000 / (2 * (16 + 3 * 4096)))
    with pytest.raises(SensorConfigError, match="within 50 % of a rate this clock"):
        ads131m0x.choose_osr(300_000, 5000)  # the fastest is 300000 / 128 = 2343.75 sps


def test_register_words_come_from_the_firmware():
    words = ads131m0x.register_words("ads131m04", 3, 64, 1, 16)
    assert words == ads131m0x.RegisterWords(mode=0x0100, clock=0x0800 | 0x20 | 0x2, gain1=0x0000,
                                            cfg=3 << 9 | 0x100)
    assert ads131m0x.register_words("ads131m02", 0, 8192, 128, None).clock == 0x0100 | 6 << 2 | 0x2


def test_the_frame_reader_takes_its_channel_and_refuses_crc_errors_and_resets():
    frames = bytearray(ads131m0x.encode_frames("ads131m04", np.array([123, -38000, 8388607, -8388608]), 2,
                                               reset=np.array([False, False, True, False])))
    assert len(frames) == 4 * 18
    frames[18 + 7] ^= 0x10  # one bit of the second frame's channel-2 word
    reader = ads131m0x.FrameReader("ads131m04", 2)
    counts, status = reader.decode(bytes(frames))
    assert counts.tolist() == [123, 0, 0, 0]
    assert status.tolist() == [ads131m0x.OK, ads131m0x.ERR_CRC, ads131m0x.ERR_RESET, ads131m0x.ERR_RESET]
    reader.restart()
    counts, status = reader.decode(bytes(frames[54:]))
    assert counts.tolist() == [-8388608] and status.tolist() == [ads131m0x.OK]
    assert ads131m0x.crc16(b"123456789") == 0x29B1
    with pytest.raises(SensorConfigError, match="adc_channel"):
        ads131m0x.FrameReader("ads131m02", 2)


def test_load_cell_options(tmp_path):
    printer, _ = printer_with(tmp_path, chip="ads131m04",
                              clock="clock_freq: 8192000\nsample_rate: 2000\nadc_channel: 3\ngain: 32")
    options = printer.lookup_object("load_cell_probe").load_cell.options
    assert (options.sample_rate_sps, options.osr, options.adc_channel, options.gain) == (2000.0, 2048, 3, "32")
    assert options.ads131m0x_registers.gain1 == 0x5555 and options.spi_speed_hz == 4_000_000
    assert printer.backend.params.chip == "ads131m04" and printer.backend.params.sample_rate_sps == 2000.0
    # A clock from a [static_pwm_clock] output: 8 MHz / (2 x 8192) = 488.28 sps for the default 500.
    printer, _ = printer_with(tmp_path, clock="pwm_clock: adc_clock",
                              extra="\n[static_pwm_clock adc_clock]\npin: PA8\nfrequency: 8000000\n")
    assert printer.lookup_object("load_cell_probe").load_cell.options.sample_rate_sps == pytest.approx(488.28125)
    assert printer.backend.params.sample_rate_sps == pytest.approx(488.28125)


@pytest.mark.parametrize("clock, message", [
    ("clock_freq: 8192000\nadc_channel: 2", "adc_channel = 2: must be at most 1"),
    ("clock_freq: 100000", "clock_freq = 100000: must be at least 300000"),
    ("clock_freq: 300000\nsample_rate: 5000", "sample_rate = 5000: not possible; allowed: within 50 % of a rate "
                                             "this clock (300000 Hz) gives: 9.15527, "),
    ("pwm_clock: nope", "pwm_clock = nope: needs a [static_pwm_clock nope] section with a frequency"),
    ("", "clock_freq: "),
    ("clock_freq: 8192000\nglobal_chop_delay: 3", "global_chop_delay = 3"),
])
def test_bad_options_name_the_option_and_what_is_allowed(tmp_path, clock, message):
    assert message in config_error(tmp_path, clock=clock)


def test_the_virtual_chip_turns_corrupted_frames_into_sensor_errors():
    # The glitchy cable flips bits on the wire: an HX717's wrong samples reach the host, an
    # ADS131M02's frames fail their CRC and become sensor errors.
    far_off = {}
    for chip, rate in (("hx717", 320), ("ads131m02", 500)):
        vp = VirtualPrinter.from_scenario("glitchy", seed=3, chip=chip, sample_rate_sps=rate)
        vp.dwell(60.0)
        batch = vp.take_samples()
        far_off[chip] = int(np.sum(np.abs(batch.counts - np.median(batch.counts)) > 20000))
        if chip == "ads131m02":
            assert batch.errors >= 20 and len(batch.counts) + batch.errors == pytest.approx(30000, abs=2)
    assert far_off == {"hx717": far_off["hx717"], "ads131m02": 0} and far_off["hx717"] >= 20


def test_probing_on_an_ads131m02(tmp_path):
    printer, responses = printer_with(tmp_path, clock="clock_freq: 8192000\nsample_rate: 1000\nadc_channel: 1")
    printer.gcode.run_script("G28\nPROBE_ACCURACY SAMPLES=5")
    summary = responses[-1]
    assert summary.startswith("// probe accuracy results:")
    spread_mm = float(summary.split("range ")[1].split(",")[0])
    assert spread_mm < 0.002  # 5 taps within 2 um


def test_a_crc_failure_or_a_reset_is_named_in_the_error(tmp_path):
    printer, _ = printer_with(tmp_path)
    printer.gcode.run_script("LOAD_CELL_TARE")
    printer.backend.inject_fault("chip_reset", gap_s=0.02)  # a brown-out: the chip restarts with its defaults
    with pytest.raises(GCodeError) as info:
        printer.gcode.run_script("LOAD_CELL_TARE")
    assert "errors while sampling (the ADS131M02 reported a reset (a brown-out on its supply): its settings are " \
           "gone and its frames are refused until FIRMWARE_RESTART sets it up again)" in str(info.value)
    printer.backend.dwell(5.0)
    with pytest.raises(GCodeError, match="reported a reset"):  # sticky: still refused seconds later
        printer.gcode.run_script("LOAD_CELL_TARE")
    printer.gcode.run_script("FIRMWARE_RESTART\nLOAD_CELL_TARE")  # a new chip set-up
    # A bit flipped on the wire: the frame's CRC fails, and the error says so.
    printer, _ = printer_with(tmp_path, world="glitch_rate_per_s: 50\n")
    with pytest.raises(GCodeError, match=r"the ADS131M02's frames failed their CRC \(\d+ so far\): check the SPI"):
        printer.gcode.run_script("LOAD_CELL_TARE")


def test_a_corrupt_frame_fault_fails_the_crc_instead_of_reaching_the_host():
    results = {}
    for chip, rate in (("hx717", 320), ("ads131m02", 500)):
        vp = VirtualPrinter.from_scenario("clean", seed=3, chip=chip, sample_rate_sps=rate)
        vp.dwell(1.0)
        vp.take_samples()
        vp.inject_fault("corrupt_frame", count=3, spacing_s=0.25)
        vp.dwell(2.0)
        batch = vp.take_samples()
        far_off = int(np.sum(np.abs(batch.counts - np.median(batch.counts)) > 20000))
        results[chip] = (far_off, batch.errors, vp.sensor_error_note())
    assert results["hx717"] == (3, 0, "")
    assert results["ads131m02"] == (0, 3, "the ADS131M02's frames failed their CRC (3 so far): check the SPI "
                                           "wiring, its grounding and the cable length")
