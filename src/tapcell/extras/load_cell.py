"""`[load_cell]` / `[load_cell NAME]`: a digital scale on a load-cell sensor.

Three parts:

* options: `LoadCellOptions` and `read_load_cell_options(section)`, shared with
  `[load_cell_probe]` (which takes every [load_cell] option);
* `LoadCell`: the sample stream of one sensor (a 1 s ring buffer for the status,
  clients for whoever needs every sample), tare, counts -> grams, status;
* the G-code commands LOAD_CELL_DIAGNOSTIC, LOAD_CELL_CALIBRATE (with the temporary
  TARE / CALIBRATE / ACCEPT / ABORT), LOAD_CELL_TARE and LOAD_CELL_READ, registered by
  `register_load_cell_commands` so `[load_cell_probe]` gets the same commands.

The math lives in `tapcell.scale`; this module is the imperative shell around it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from tapcell import scale
from tapcell.host.config import ConfigSection
from tapcell.host.gcode import GCodeCommand, GCodeDispatch, GCodeError
from tapcell.mcu import ads131m0x, sensors
from tapcell.host.backend import SampleBatch

# ---------------------------------------------------------------------------
# Options

SENSOR_TYPES = ("hx711", "hx717", "ads1220", "ads131m02", "ads131m04")
ORIENTATIONS = {"normal": False, "inverted": True}


@dataclass(frozen=True)
class LoadCellOptions:
    """Every [load_cell] option, validated. Sensor-specific fields are None when unused."""

    sensor_type: str
    sample_rate_sps: float
    gain: str  # as written in the config: "A-128" (HX71x) or "128" (ADS1220)
    counts_per_gram: float | None
    reference_tare_counts: int | None
    inverted: bool
    # HX711 / HX717 (bit-bang)
    sclk_pin: str | None = None
    dout_pin: str | None = None
    # ADS1220 (SPI)
    cs_pin: str | None = None
    data_ready_pin: str | None = None
    spi_speed_hz: int | None = None
    spi_bus: str | None = None
    spi_software_sclk_pin: str | None = None
    spi_software_mosi_pin: str | None = None
    spi_software_miso_pin: str | None = None
    input_mux: str | None = None
    vref: str | None = None
    pga_bypass: bool | None = None  # the effective value (forced on for AVSS inputs)
    ads1220_registers: bytes | None = None
    # ADS131M02 / ADS131M04 (SPI, external clock)
    adc_channel: int | None = None
    clock_freq_hz: float | None = None
    osr: int | None = None
    global_chop_delay: int | None = None  # None: global chop off
    ads131m0x_registers: ads131m0x.RegisterWords | None = None

    @property
    def is_calibrated(self) -> bool:
        return self.counts_per_gram is not None and self.reference_tare_counts is not None


def higher_gain(sensor_type: str, gain: str) -> str | None:
    """The next higher gain the sensor offers, as written in a config; None at the top (or for a
    sensor whose gains this does not know). An HX71x stays on its channel: B-64 is not A-128's
    neighbour, it reads other pins."""
    if sensor_type in sensors.HX71X_GAINS:
        channel, _, value = gain.partition("-")
        on_channel = [int(g.partition("-")[2]) for g in sensors.HX71X_GAINS[sensor_type]
                      if g.startswith(channel + "-")]
        higher = sorted(v for v in on_channel if v > int(value))
        return f"{channel}-{higher[0]}" if higher else None
    if sensor_type == "ads1220":
        higher = [g for g in sensors.ADS1220_GAINS if g > int(gain)]
        return str(higher[0]) if higher else None
    return None


def _read_hx71x_options(section: ConfigSection, chip: str) -> dict:
    rates = sensors.SAMPLE_RATES_SPS[chip]
    return dict(
        sclk_pin=section.get("sclk_pin"),
        dout_pin=section.get("dout_pin"),
        gain=section.getchoice("gain", list(sensors.HX71X_GAINS[chip]), default=sensors.HX71X_GAINS[chip][0]),
        sample_rate_sps=float(
            section.getchoice("sample_rate", list(rates), default=sensors.DEFAULT_SAMPLE_RATE_SPS[chip])
        ),
    )


def _read_spi_options(section: ConfigSection) -> dict:
    software_pins = {
        option: section.get(option, None)
        for option in ("spi_software_sclk_pin", "spi_software_mosi_pin", "spi_software_miso_pin")
    }
    spi_bus = section.get("spi_bus", None)
    given = [option for option, pin in software_pins.items() if pin is not None]
    if given and len(given) != len(software_pins):
        missing = [option for option in software_pins if option not in given]
        raise section.error(missing[0], "software SPI needs all of spi_software_sclk_pin, "
                                        "spi_software_mosi_pin and spi_software_miso_pin")
    if given and spi_bus is not None:
        raise section.error("spi_bus", "choose either spi_bus or the spi_software_*_pin options, not both")
    return dict(spi_bus=spi_bus, **software_pins)


def _read_ads1220_options(section: ConfigSection) -> dict:
    rates = sensors.SAMPLE_RATES_SPS["ads1220"]
    sample_rate = section.getchoice("sample_rate", list(rates), default=sensors.DEFAULT_SAMPLE_RATE_SPS["ads1220"])
    gain = section.getchoice("gain", list(sensors.ADS1220_GAINS), default=128)
    input_mux = section.getchoice("input_mux", list(sensors.ADS1220_INPUT_MUXES), default="AIN0_AIN1")
    vref = section.getchoice("vref", list(sensors.ADS1220_VREFS), default="internal")
    pga_bypass = section.getboolean("pga_bypass", False)
    # The faster SPI clock only works with the turbo rates (the chip's clock doubles).
    speed_for_rate = sensors.ads1220_spi_speed_hz(sample_rate)
    spi_speed = section.getchoice("spi_speed", sorted(sensors.ADS1220_SPI_SPEED_HZ.values()), default=speed_for_rate)
    if spi_speed > speed_for_rate:
        raise section.error("spi_speed", f"{spi_speed} needs a turbo sample_rate; with sample_rate {sample_rate}"
                                         f" use {speed_for_rate}")
    try:
        registers = sensors.ads1220_registers(gain, pga_bypass, sample_rate, input_mux, vref)
    except sensors.SensorConfigError as exc:
        raise section.error(exc.option, f"not allowed with these settings; allowed: {exc.allowed}") from None
    return dict(
        cs_pin=section.get("cs_pin"),
        data_ready_pin=section.get("data_ready_pin"),
        spi_speed_hz=spi_speed,
        **_read_spi_options(section),
        gain=str(gain),
        sample_rate_sps=float(sample_rate),
        input_mux=input_mux,
        vref=vref,
        pga_bypass=sensors.ads1220_effective_pga_bypass(gain, pga_bypass, input_mux),
        ads1220_registers=registers,
    )


def _ads131m0x_clock_hz(section: ConfigSection) -> float:
    """clock_freq, or the frequency of the [static_pwm_clock NAME] that pwm_clock names."""
    low, high = ads131m0x.CLOCK_HZ_RANGE
    pwm_clock = section.get("pwm_clock", None)
    if pwm_clock is None:
        return float(section.getint("clock_freq", minval=low, maxval=high))
    if section.has_option("clock_freq"):
        raise section.error("clock_freq", "give clock_freq or pwm_clock, not both")
    clock_section = f"static_pwm_clock {pwm_clock.strip()}"
    text = section.config.peek(clock_section, "frequency")
    if text is None:
        raise section.error("pwm_clock", f"needs a [{clock_section}] section with a frequency")
    try:
        frequency = float(text)
    except ValueError:
        raise section.error("pwm_clock", f"[{clock_section}] frequency = {text.strip()} is not a number") from None
    if not low <= frequency <= high:
        raise section.error("pwm_clock", f"[{clock_section}] frequency = {frequency:g} Hz is outside the chip's "
                                         f"clock range ({low} to {high} Hz)")
    return frequency


def _read_ads131m0x_options(section: ConfigSection, chip: str) -> dict:
    channels = ads131m0x.CHANNELS[chip]
    channel = section.getint("adc_channel", 0, minval=0, maxval=channels - 1)
    clock_hz = _ads131m0x_clock_hz(section)
    gain = section.getchoice("gain", list(ads131m0x.GAINS), default=128)
    chop = section.getboolean("enable_global_chop", False)
    chop_delay = section.getchoice("global_chop_delay", list(ads131m0x.CHOP_DELAYS), default=16)
    asked_sps = section.getfloat("sample_rate", ads131m0x.DEFAULT_SAMPLE_RATE_SPS, above=0.0, maxval=clock_hz / 2)
    try:
        osr, rate_sps = ads131m0x.choose_osr(clock_hz, asked_sps, chop_delay if chop else None)
    except sensors.SensorConfigError as exc:
        raise section.error("sample_rate", f"not possible; allowed: {exc.allowed}") from None
    spi_speed = section.getint("spi_speed", ads131m0x.DEFAULT_SPI_SPEED_HZ, minval=100_000, maxval=25_000_000)
    return dict(
        cs_pin=section.get("cs_pin"),
        data_ready_pin=section.get("data_ready_pin"),
        spi_speed_hz=spi_speed,
        **_read_spi_options(section),
        gain=str(gain),
        sample_rate_sps=rate_sps,
        adc_channel=channel,
        clock_freq_hz=clock_hz,
        osr=osr,
        global_chop_delay=chop_delay if chop else None,
        ads131m0x_registers=ads131m0x.register_words(chip, channel, osr, gain, chop_delay if chop else None),
    )


def read_load_cell_options(section: ConfigSection) -> LoadCellOptions:
    """Reads and validates every [load_cell] option of `section` (also used by [load_cell_probe]).

    Errors are ConfigErrors naming the file, section, option, value and what is allowed.
    """
    sensor_type = section.getchoice("sensor_type", list(SENSOR_TYPES))
    if sensor_type == "ads1220":
        sensor_options = _read_ads1220_options(section)
    elif sensor_type in ads131m0x.CHANNELS:
        sensor_options = _read_ads131m0x_options(section, sensor_type)
    else:
        sensor_options = _read_hx71x_options(section, sensor_type)
    return LoadCellOptions(
        sensor_type=sensor_type,
        counts_per_gram=section.getfloat("counts_per_gram", None, minval=scale.MIN_COUNTS_PER_GRAM,
                                         maxval=scale.MAX_COUNTS_24BIT),
        reference_tare_counts=section.getint("reference_tare_counts", None, minval=-scale.MAX_COUNTS_24BIT - 1,
                                             maxval=scale.MAX_COUNTS_24BIT),
        inverted=section.getchoice("sensor_orientation", ORIENTATIONS, default=False),
        **sensor_options,
    )


# ---------------------------------------------------------------------------
# The load cell: sample stream, tare, grams, status

# How long LOAD_CELL_TARE / READ / CALIBRATE average, and the span the status covers:
# the guide documents 1 s (we do not copy another implementation's 0.5 s).
AVERAGE_TIME_S = 1.0
DIAGNOSTIC_TIME_S = 10.0
DIAGNOSTIC_PROGRESS_EVERY_S = 2.0


def sensor_error_note(backend) -> str:
    """' (why)' when the sensor can tell why it refused samples (an ADS131M0x's CRC failures or its
    reset; the backend's `sensor_error_note`), else ''."""
    note_of = getattr(backend, "sensor_error_note", None)
    note = note_of() if note_of is not None else ""
    return f" ({note})" if note else ""


class LoadCellError(GCodeError):
    """A load-cell operation failed (no samples, sensor errors, saturation...)."""


class ClientHandle:
    """Returned by `LoadCell.add_client`; `remove()` stops the callbacks."""

    def __init__(self, clients: list, callback: Callable[[SampleBatch], None]):
        self._clients = clients
        self._callback = callback

    def remove(self) -> None:
        if self._callback in self._clients:
            self._clients.remove(self._callback)


def _concatenate(batches: list[SampleBatch]) -> SampleBatch:
    return SampleBatch(
        t_s=np.concatenate([b.t_s for b in batches]) if batches else np.zeros(0),
        counts=np.concatenate([b.counts for b in batches]) if batches else np.zeros(0, dtype=np.int32),
        errors=sum(b.errors for b in batches),
        overflows=sum(b.overflows for b in batches),
    )


class LoadCell:
    """One load cell: its options, its sensor's sample stream, tare and calibration.

    `sensor` is anything with `take_samples() -> SampleBatch` (the samples since the
    last call); by default the section's virtual sensor (see `open_sensor`). The
    printer's backend (the virtual printer) owns time: `collect` advances it with `dwell`.
    """

    def __init__(self, name: str, options: LoadCellOptions, printer, sensor=None,
                 counts_range: scale.CountsRange = scale.SENSOR_24BIT):
        self.printer = printer
        self.name = name
        self.options = options
        self.counts_range = counts_range
        self.sensor = sensor if sensor is not None else open_sensor(printer, name, options)
        self.counts_per_gram: float | None = options.counts_per_gram
        self.reference_tare_counts: int | None = options.reference_tare_counts
        # Start-up tare: the calibration's zero, until someone tares again.
        self.tare_counts: int | None = options.reference_tare_counts
        self.errors = 0
        self.overflows = 0
        self._clients: list[Callable[[SampleBatch], None]] = []
        self._recent_counts = np.zeros(0, dtype=np.int64)
        self._recent_size = max(1, int(round(options.sample_rate_sps * AVERAGE_TIME_S)))

    # -- the stream ------------------------------------------------------------

    @property
    def is_calibrated(self) -> bool:
        return self.counts_per_gram is not None and self.reference_tare_counts is not None

    def pump(self) -> None:
        """Moves the sensor's new samples into the 1 s buffer and to every client."""
        batch = self.sensor.take_samples()
        self.errors += batch.errors
        self.overflows += batch.overflows
        if len(batch.counts) == 0 and batch.errors == 0 and batch.overflows == 0:
            return
        kept = np.concatenate([self._recent_counts, np.asarray(batch.counts, dtype=np.int64)])
        self._recent_counts = kept[-self._recent_size:]
        for callback in list(self._clients):
            callback(batch)

    def add_client(self, callback: Callable[[SampleBatch], None]) -> ClientHandle:
        """Calls `callback(batch)` with every new batch of samples until removed."""
        self.pump()  # older samples belong to the time before the client existed
        self._clients.append(callback)
        return ClientHandle(self._clients, callback)

    def collect(self, duration_s: float) -> SampleBatch:
        """Lets `duration_s` of simulated time pass and returns the samples of that span."""
        batches: list[SampleBatch] = []
        handle = self.add_client(batches.append)
        try:
            self.printer.backend.dwell(duration_s)
            self.pump()
        finally:
            handle.remove()
        return _concatenate(batches)

    def collect_checked(self, duration_s: float) -> SampleBatch:
        """`collect`, refusing spans with no samples, sensor errors or saturation."""
        batch = self.collect(duration_s)
        if len(batch.counts) == 0 and not batch.errors:
            raise LoadCellError(
                f"No samples returned from sensor! ({self.name}: nothing in {duration_s:g} s;"
                " check the sensor wiring and its sensor_type / pins)"
            )
        if batch.errors:  # samples that came and were refused (a chip that says why is asked)
            raise LoadCellError(f"Sensor reported {batch.errors} errors while sampling"
                                f"{sensor_error_note(self.printer.backend)}")
        if np.any(scale.saturated_mask(batch.counts, self.counts_range)):
            raise LoadCellError("Some samples are saturated (+/-100%)")
        return batch

    def average_counts(self, duration_s: float = AVERAGE_TIME_S) -> float:
        return float(np.mean(self.collect_checked(duration_s).counts))

    # -- tare and conversion ---------------------------------------------------

    def tare(self, duration_s: float = AVERAGE_TIME_S) -> int:
        """Makes the current force the zero: averages `duration_s` of samples."""
        return self.set_tare(self.average_counts(duration_s))

    def set_tare(self, tare_counts: float) -> int:
        """Makes `tare_counts` (e.g. a probe's own short pre-tap average) the zero."""
        self.tare_counts = int(round(tare_counts))
        return self.tare_counts

    def set_calibration(self, counts_per_gram: float, reference_tare_counts: int) -> None:
        if counts_per_gram < scale.MIN_COUNTS_PER_GRAM:
            raise LoadCellError(
                f"counts_per_gram {counts_per_gram:.6f} is below the minimum of {scale.MIN_COUNTS_PER_GRAM:g}"
            )
        self.counts_per_gram = float(counts_per_gram)
        self.reference_tare_counts = int(reference_tare_counts)
        self.tare_counts = int(reference_tare_counts)

    def counts_to_grams(self, counts) -> np.ndarray | None:
        """Grams relative to the tare; None until calibrated and tared."""
        if not self.is_calibrated or self.tare_counts is None:
            return None
        return scale.counts_to_grams(counts, self.tare_counts, self.counts_per_gram, self.options.inverted)

    def percent(self, counts) -> float:
        return float(scale.counts_to_percent(counts, self.counts_range))

    def get_status(self, eventtime=None) -> dict:
        self.pump()
        grams = self.counts_to_grams(self._recent_counts) if len(self._recent_counts) else None
        return {
            "is_calibrated": self.is_calibrated,
            "counts_per_gram": self.counts_per_gram,
            "reference_tare_counts": self.reference_tare_counts,
            "tare_counts": self.tare_counts,
            "force_g": None if grams is None else round(float(np.mean(grams)), 1),
            "min_force_g": None if grams is None else round(float(np.min(grams)), 1),
            "max_force_g": None if grams is None else round(float(np.max(grams)), 1),
            "errors": self.errors,
            "overflows": self.overflows,
            "sample_rate": self.options.sample_rate_sps,
        }


# ---------------------------------------------------------------------------
# G-code commands

CALIBRATION_COMMANDS = ("TARE", "CALIBRATE", "ACCEPT", "ABORT")


class _CalibrationSession:
    """The interactive LOAD_CELL_CALIBRATE: TARE, CALIBRATE GRAMS=, ACCEPT or ABORT.

    Its four commands exist only while the session runs; a failed step keeps the
    session open so the user can fix the cause and repeat it.
    """

    def __init__(self, gcode: GCodeDispatch, load_cell: LoadCell):
        self.gcode = gcode
        self.load_cell = load_cell
        self.tare_counts: float | None = None
        self.result: scale.CalibrationResult | None = None

    def start(self, gcmd: GCodeCommand) -> None:
        if any(self.gcode.is_registered(name) for name in CALIBRATION_COMMANDS):
            raise LoadCellError("Already Calibrating a Load Cell. Use ABORT to quit.")
        handlers = {"TARE": self.cmd_tare, "CALIBRATE": self.cmd_calibrate,
                    "ACCEPT": self.cmd_accept, "ABORT": self.cmd_abort}
        helps = {"TARE": "Load cell calibration: take the zero reading with no load",
                 "CALIBRATE": "Load cell calibration: reading under a known load, CALIBRATE GRAMS=nnn",
                 "ACCEPT": "Load cell calibration: keep the result (then SAVE_CONFIG)",
                 "ABORT": "Load cell calibration: quit without changing anything"}
        for name, handler in handlers.items():
            self.gcode.register_command(name, handler, desc=helps[name])
        gcmd.respond_info(
            f"Starting load cell calibration of '{self.load_cell.name}':\n"
            "1. Remove all load from the cell, then run TARE.\n"
            "2. Apply a known load, then run CALIBRATE GRAMS=nnn (50 to 25000 grams).\n"
            "3. Run ACCEPT to keep the result; SAVE_CONFIG then writes it to the config file.\n"
            "Run ABORT to quit at any time."
        )

    def _end(self) -> None:
        for name in CALIBRATION_COMMANDS:
            self.gcode.unregister_command(name)

    def cmd_tare(self, gcmd: GCodeCommand) -> None:
        self.result = None  # a new zero invalidates an earlier CALIBRATE
        self.tare_counts = self.load_cell.average_counts()
        lines = [f"Load cell tare value: {self.load_cell.percent(self.tare_counts):.2f}% ({int(self.tare_counts)})"]
        warning = scale.tare_warning(self.tare_counts, self.load_cell.counts_range)
        if warning:
            lines.append(warning)
        lines.append("Now apply a known load to the cell and run CALIBRATE GRAMS=nnn")
        gcmd.respond_info("\n".join(lines))

    def cmd_calibrate(self, gcmd: GCodeCommand) -> None:
        grams = gcmd.get_float("GRAMS", minval=scale.MIN_CALIBRATION_GRAMS, maxval=scale.MAX_CALIBRATION_GRAMS)
        if self.tare_counts is None:
            raise LoadCellError("Run TARE with no load on the cell before CALIBRATE GRAMS=nnn")
        batch = self.load_cell.collect(AVERAGE_TIME_S)
        if len(batch.counts) == 0:
            raise LoadCellError(f"No samples returned from sensor! ({self.load_cell.name})")
        if batch.errors:
            raise LoadCellError(f"Sensor reported {batch.errors} errors while sampling"
                                f"{sensor_error_note(self.load_cell.printer.backend)}")
        loaded_counts = float(np.mean(batch.counts))
        result = scale.evaluate_calibration(
            self.tare_counts, loaded_counts, grams,
            any_saturated=bool(np.any(scale.saturated_mask(batch.counts, self.load_cell.counts_range))),
            inverted=self.load_cell.options.inverted, counts_range=self.load_cell.counts_range,
            higher_gain=higher_gain(self.load_cell.options.sensor_type, self.load_cell.options.gain),
        )
        if result.error:
            self.result = None
            raise LoadCellError(result.error)
        self.result = result
        lines = [
            f"Calibration value: {self.load_cell.percent(loaded_counts):.2f}% ({int(loaded_counts)}),"
            f" Counts/gram: {result.counts_per_gram:.6f}, Total capacity: +/- {result.capacity_kg:.2f}Kg",
            *result.warnings,
            "Accept calibration with the ACCEPT command.",
        ]
        gcmd.respond_info("\n".join(lines))

    def cmd_accept(self, gcmd: GCodeCommand) -> None:
        if self.result is None:
            missing = "TARE, then CALIBRATE GRAMS=nnn," if self.tare_counts is None else "CALIBRATE GRAMS=nnn"
            raise LoadCellError(
                f"Load cell calibration is incomplete: run {missing} before ACCEPT (or ABORT to quit)"
            )
        counts_per_gram = round(self.result.counts_per_gram, 6)
        reference_tare_counts = int(self.tare_counts)
        self.load_cell.set_calibration(counts_per_gram, reference_tare_counts)
        config = self.load_cell.printer.config
        config.set(self.load_cell.name, "counts_per_gram", f"{counts_per_gram:.6f}")
        config.set(self.load_cell.name, "reference_tare_counts", str(reference_tare_counts))
        self._end()
        self.load_cell.printer.send_event("load_cell:calibrate", self.load_cell)
        gcmd.respond_info(
            "Load cell calibration settings:\n\n"
            f"counts_per_gram: {counts_per_gram:.6f}\n"
            f"reference_tare_counts: {reference_tare_counts}\n\n"
            "The SAVE_CONFIG command will update the printer config file with the above and restart the printer."
        )

    def cmd_abort(self, gcmd: GCodeCommand) -> None:
        self._end()
        gcmd.respond_info("Load cell calibration aborted")


class _LoadCellCommands:
    """The LOAD_CELL_* command handlers of one load cell."""

    def __init__(self, gcode: GCodeDispatch, load_cell: LoadCell):
        self.gcode = gcode
        self.load_cell = load_cell

    def cmd_calibrate(self, gcmd: GCodeCommand) -> None:
        _CalibrationSession(self.gcode, self.load_cell).start(gcmd)

    def cmd_tare(self, gcmd: GCodeCommand) -> None:
        tare_counts = self.load_cell.tare()
        gcmd.respond_info(f"Load cell tare value: {self.load_cell.percent(tare_counts):.2f}% ({tare_counts})")

    def cmd_read(self, gcmd: GCodeCommand) -> None:
        counts = self.load_cell.average_counts()
        percent = self.load_cell.percent(counts)
        grams = self.load_cell.counts_to_grams(counts)
        shown = "---.-g" if grams is None else f"{float(grams):.1f}g"
        gcmd.respond_info(f"{shown} ({percent:.2f}%)")

    def cmd_diagnostic(self, gcmd: GCodeCommand) -> None:
        load_cell = self.load_cell
        gcmd.respond_info(f"Collecting load cell data for {DIAGNOSTIC_TIME_S:g} seconds...")
        batches = []
        collected_s = 0.0
        while collected_s < DIAGNOSTIC_TIME_S - 1e-9:
            step_s = min(DIAGNOSTIC_PROGRESS_EVERY_S, DIAGNOSTIC_TIME_S - collected_s)
            batches.append(load_cell.collect(step_s))
            collected_s += step_s
            if collected_s < DIAGNOSTIC_TIME_S - 1e-9:
                samples = sum(len(b.counts) for b in batches)
                gcmd.respond_info(f"... {collected_s:g} of {DIAGNOSTIC_TIME_S:g} s, {samples} samples")
        batch = _concatenate(batches)
        if batch.errors or batch.overflows:
            lines = [f"Sensor reported errors: {batch.errors} errors, {batch.overflows} overflows"]
        else:
            lines = ["Sensor reported no errors"]
        if len(batch.counts) == 0:
            gcmd.respond_info("\n".join(lines))
            raise LoadCellError("No samples returned from sensor! Check the wiring and the sensor_type / pins.")
        stats = scale.diagnostic_statistics(
            batch.t_s, batch.counts, tare_counts=load_cell.tare_counts,
            counts_per_gram=load_cell.counts_per_gram if load_cell.is_calibrated else None,
            inverted=load_cell.options.inverted, counts_range=load_cell.counts_range,
        )
        lines.append(f"Samples Collected: {stats.samples_collected}")
        if stats.measured_rate_sps is not None:
            lines.append(f"Measured samples per second: {stats.measured_rate_sps:.1f},"
                         f" configured: {load_cell.options.sample_rate_sps:.1f}")
        lines += [
            f"Good samples: {stats.good_samples}, Saturated samples: {stats.saturated_samples},"
            f" Unique values: {stats.unique_values}",
            f"Sample range: [{stats.min_percent:.2f}% to {stats.max_percent:.2f}%]",
            f"Sample range / sensor capacity: {stats.range_share_of_capacity_percent:.5f}%",
        ]
        if stats.min_g is not None:
            lines.append(f"Sample range in grams: [{stats.min_g:.1f}g to {stats.max_g:.1f}g]"
                         f" ({stats.max_g - stats.min_g:.1f}g wide)")
        gcmd.respond_info("\n".join(lines))


COMMAND_HELP = {
    "LOAD_CELL_DIAGNOSTIC": "Collect 10 s of load cell samples and report the sensor's health",
    "LOAD_CELL_CALIBRATE": "Start the interactive load cell calibration (TARE, CALIBRATE GRAMS=, ACCEPT)",
    "LOAD_CELL_TARE": "Make the current force on the load cell the zero",
    "LOAD_CELL_READ": "Read the force on the load cell, averaged over 1 s",
}


def is_default_load_cell(config, section_name: str) -> bool:
    """The unnamed cell answers LOAD_CELL_* without LOAD_CELL=; with both an unnamed
    [load_cell] and a [load_cell_probe] there is no default (the user must say which)."""
    unnamed = [name for name in ("load_cell", "load_cell_probe") if config.has_section(name)]
    return unnamed == [section_name]


def register_load_cell_commands(gcode: GCodeDispatch, load_cell: LoadCell, mux_value: str) -> None:
    """Registers LOAD_CELL_* for `load_cell` under LOAD_CELL=`mux_value` (and as the
    default when it is the only unnamed load cell)."""
    commands = _LoadCellCommands(gcode, load_cell)
    handlers = {
        "LOAD_CELL_DIAGNOSTIC": commands.cmd_diagnostic,
        "LOAD_CELL_CALIBRATE": commands.cmd_calibrate,
        "LOAD_CELL_TARE": commands.cmd_tare,
        "LOAD_CELL_READ": commands.cmd_read,
    }
    values = [mux_value]
    if is_default_load_cell(load_cell.printer.config, load_cell.name):
        values.append(None)
    for name, handler in handlers.items():
        for value in values:
            gcode.register_mux_command(name, "LOAD_CELL", value, handler, desc=COMMAND_HELP[name])


# ---------------------------------------------------------------------------
# Printer assembly


def owns_primary_sensor(config, section_name: str) -> bool:
    """Whether this load cell is the printer's own (toolhead) cell.

    The virtual printer has one cell with contact physics under the nozzle; it belongs
    to [load_cell_probe] if there is one, else to the unnamed [load_cell], else to the
    first [load_cell NAME]. Every other load cell gets a sensor of its own.
    """
    for candidate in ("load_cell_probe", "load_cell"):
        if config.has_section(candidate):
            return section_name == candidate
    named = [s.get_name() for s in config.get_prefix_sections("load_cell ")]
    return bool(named) and section_name == named[0]


def open_sensor(printer, section_name: str, options: LoadCellOptions):
    """The virtual sensor behind a load cell section (see owns_primary_sensor)."""
    if owns_primary_sensor(printer.config, section_name):
        return printer.backend
    return printer.backend.add_sensor(section_name, options.sensor_type, options.sample_rate_sps)


def _load(section: ConfigSection, printer) -> LoadCell:
    options = read_load_cell_options(section)
    name = section.get_name()
    load_cell = LoadCell(name, options, printer)
    register_load_cell_commands(printer.gcode, load_cell, name.split()[-1])
    return load_cell


def load_config(section: ConfigSection, printer) -> LoadCell:
    """[load_cell]"""
    return _load(section, printer)


def load_config_prefix(section: ConfigSection, printer) -> LoadCell:
    """[load_cell NAME]"""
    return _load(section, printer)
