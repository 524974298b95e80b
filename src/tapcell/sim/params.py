"""Every knob of the virtual printer in one flat, documented dataclass.

A scenario is a set of overrides on these defaults; `[virtual_printer]` options and
`VirtualPrinter.from_scenario(..., **overrides)` use the same names. Defaults describe a
well-built bed slinger with a toolhead load cell read by an HX717 at 320 sps.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields

CHIP_RATES_SPS: dict[str, tuple[float, ...]] = {
    "hx711": (10, 80),
    "hx717": (10, 20, 80, 320),
    # ADS1220 normal-mode rates, then turbo-mode rates (90 appears in both lists).
    "ads1220": (20, 45, 90, 175, 330, 600, 1000, 40, 180, 350, 660, 1200, 2000),
}
# ADS131M02/M04 at their usual 8.192 MHz clock: fclk / (2 OSR) for OSR 128 .. 16384, then 64 (turbo).
# Another clock gives other rates: the printer's config decides (tapcell.sim.machine).
ADS131M0X_RATES_SPS = (250, 500, 1000, 2000, 4000, 8000, 16000, 32000, 64000)
CHIP_RATES_SPS["ads131m02"] = CHIP_RATES_SPS["ads131m04"] = ADS131M0X_RATES_SPS
CHIP_DEFAULT_RATE_SPS = {"hx711": 80, "hx717": 320, "ads1220": 660, "ads131m02": 500, "ads131m04": 500}
CHIP_GAINS = {"hx711": (128, 64, 32), "hx717": (128, 64, 8), "ads1220": (1, 2, 4, 8, 16, 32, 64, 128),
              "ads131m02": (1, 2, 4, 8, 16, 32, 64, 128), "ads131m04": (1, 2, 4, 8, 16, 32, 64, 128)}
# Extra delay between the end of a conversion window and data-ready, in conversion periods.
# HX71x: the result is ready as the window closes. ADS1220: its sinc3 decimator puts the
# centre of the response ~1.5 periods back, modelled as one window plus one period of pipeline.
CHIP_PIPELINE_PERIODS = {"hx711": 0.0, "hx717": 0.0, "ads1220": 1.0, "ads131m02": 1.0, "ads131m04": 1.0}

SHEETS: dict[str, dict[str, float]] = {
    # stiffness of the sheet + magnet + bed plate under a 0.4 mm nozzle, and how long (µm)
    # the soft, nonlinear first touch lasts before the force rises linearly.
    "smooth_pei": {"stiffness_g_um": 150.0, "onset_um": 2.0},
    "textured_pei": {"stiffness_g_um": 90.0, "onset_um": 8.0},
    "soft": {"stiffness_g_um": 8.0, "onset_um": 25.0},
}


# Ranges shared by many knobs: sizes and positions (10 m), stiffnesses, and the 24-bit chip's span.
MAX_SIZE_MM = 10_000.0
MAX_STIFFNESS_G_UM = 10_000.0
COUNTS_SPAN = float(1 << 24)


def _p(default, doc: str, unit: str = "", choices: tuple | None = None, minval=None, maxval=None):
    return field(default=default, metadata={"doc": doc, "unit": unit, "choices": choices,
                                            "minval": minval, "maxval": maxval})


@dataclass(frozen=True)
class SimParams:
    # --- machine and motion -------------------------------------------------------
    bed_x_mm: float = _p(235.0, "bed size along X", "mm", minval=10.0, maxval=MAX_SIZE_MM)
    bed_y_mm: float = _p(235.0, "bed size along Y", "mm", minval=10.0, maxval=MAX_SIZE_MM)
    max_velocity_mm_s: float = _p(300.0, "max toolhead velocity (XY)", "mm/s", minval=1.0, maxval=10_000.0)
    max_accel_mm_s2: float = _p(3000.0, "max toolhead acceleration (XY)", "mm/s²", minval=1.0, maxval=1_000_000.0)
    max_z_velocity_mm_s: float = _p(15.0, "max Z velocity", "mm/s", minval=0.1, maxval=10_000.0)
    max_z_accel_mm_s2: float = _p(200.0, "max Z acceleration", "mm/s²", minval=1.0, maxval=1_000_000.0)
    z_position_min_mm: float = _p(-2.0, "lowest commanded Z (negative lets a probe move past 0)", "mm",
                                  minval=-MAX_SIZE_MM, maxval=MAX_SIZE_MM)
    z_position_max_mm: float = _p(250.0, "highest commanded Z", "mm", minval=1.0, maxval=MAX_SIZE_MM)
    rotation_distance_xy_mm: float = _p(40.0, "X/Y rotation_distance", "mm", minval=0.1, maxval=1000.0)
    rotation_distance_z_mm: float = _p(8.0, "Z rotation_distance", "mm", minval=0.1, maxval=1000.0)
    microsteps: int = _p(16, "microsteps of every stepper", minval=1, maxval=256)
    full_steps_per_rotation: int = _p(200, "full steps per motor rotation", minval=1, maxval=10_000)
    homing_speed_mm_s: float = _p(50.0, "X/Y homing speed", "mm/s", minval=1.0, maxval=10_000.0)
    x_position_min_mm: float = _p(0.0, "lowest X the carriage reaches", "mm", minval=-MAX_SIZE_MM, maxval=MAX_SIZE_MM)
    x_position_max_mm: float = _p(0.0, "highest X the carriage reaches; 0 = bed_x_mm", "mm", minval=0.0,
                                  maxval=MAX_SIZE_MM)
    y_position_min_mm: float = _p(0.0, "lowest Y the carriage reaches", "mm", minval=-MAX_SIZE_MM, maxval=MAX_SIZE_MM)
    y_position_max_mm: float = _p(0.0, "highest Y the carriage reaches; 0 = bed_y_mm", "mm", minval=0.0,
                                  maxval=MAX_SIZE_MM)
    x_endstop_mm: float = _p(0.0, "where the X endstop switch closes", "mm", minval=-MAX_SIZE_MM, maxval=MAX_SIZE_MM)
    y_endstop_mm: float = _p(0.0, "where the Y endstop switch closes", "mm", minval=-MAX_SIZE_MM, maxval=MAX_SIZE_MM)
    start_z_mm: float = _p(10.0, "commanded Z at power on (Z is not homed)", "mm",
                           minval=-MAX_SIZE_MM, maxval=MAX_SIZE_MM)
    # --- bed ------------------------------------------------------------------------
    bed_shape: str = _p("flat", "surface model", choices=("flat", "tilted", "warped", "csv"))
    bed_z_offset_mm: float = _p(0.0, "height of the bed surface at its centre", "mm", minval=-100.0, maxval=100.0)
    bed_tilt_x_mm: float = _p(0.0, "height change across the bed along X (tilted)", "mm", minval=-100.0, maxval=100.0)
    bed_tilt_y_mm: float = _p(0.0, "height change across the bed along Y (tilted)", "mm", minval=-100.0, maxval=100.0)
    bed_warp_mm: float = _p(0.0, "peak amplitude of the smooth warp modes (warped)", "mm",
                            minval=-100.0, maxval=100.0)
    bed_warp_modes: int = _p(3, "number of smooth sine modes in the warp", minval=1, maxval=8)
    bed_csv: str = _p("", "CSV height grid (rows = Y, columns = X, mm) spread over the bed (csv)")
    sheet: str = _p("smooth_pei", "build sheet", choices=tuple(SHEETS))
    # --- contact physics --------------------------------------------------------------
    frame_stiffness_g_um: float = _p(5.0, "stiffness of frame + gantry + toolhead", "g/µm",
                                     minval=0.1, maxval=MAX_STIFFNESS_G_UM)
    cell_stiffness_g_um: float = _p(10.0, "stiffness of the load cell body", "g/µm",
                                    minval=0.1, maxval=MAX_STIFFNESS_G_UM)
    sheet_stiffness_g_um: float = _p(0.0, "sheet stiffness; 0 = the sheet's own value", "g/µm",
                                     minval=0.0, maxval=MAX_STIFFNESS_G_UM)
    contact_onset_um: float = _p(-1.0, "length of the nonlinear first touch; <0 = the sheet's own", "µm",
                                 minval=-1.0, maxval=1000.0)
    relax_fraction: float = _p(0.03, "share of a sudden load that relaxes away during a dwell", "", 
                               minval=0.0, maxval=0.5)
    relax_tau_s: float = _p(0.25, "stress-relaxation time constant", "s", minval=1e-3, maxval=1000.0)
    hysteresis_fraction: float = _p(0.04, "unloading force is this much lower than loading", "",
                                    minval=0.0, maxval=0.5)
    hysteresis_travel_um: float = _p(3.0, "travel reversing from loading to unloading curve", "µm",
                                     minval=0.01, maxval=1000.0)
    # --- sensor -------------------------------------------------------------------------
    chip: str = _p("hx717", "ADC chip", choices=tuple(CHIP_RATES_SPS))
    sample_rate_sps: float = _p(0.0, "conversion rate; 0 = the chip's default", "sps", minval=0.0, maxval=10_000.0)
    gain: int = _p(128, "PGA gain", minval=1, maxval=128)
    chip_rate_error: float = _p(0.0, "real rate / nominal rate - 1 (the chip's own oscillator)", "",
                                minval=-0.2, maxval=0.2)
    counts_per_gram: float = _p(110.0, "cell sensitivity at gain 128 (scales with gain)", "counts/g",
                                minval=0.01, maxval=100_000.0)
    zero_offset_counts: float = _p(-38000.0, "counts with no force at gain 128 (scales with gain)", "counts",
                                   minval=-COUNTS_SPAN, maxval=COUNTS_SPAN)
    cell_polarity: int = _p(1, "+1: compression raises counts; -1: lowers them", choices=(1, -1))
    white_noise_counts: float = _p(80.0, "white noise RMS per sample", "counts", minval=0.0, maxval=COUNTS_SPAN)
    pink_noise_counts: float = _p(30.0, "1/f noise RMS", "counts", minval=0.0, maxval=COUNTS_SPAN)
    hum_counts: float = _p(0.0, "mains hum amplitude before the conversion average", "counts",
                           minval=0.0, maxval=COUNTS_SPAN)
    hum_hz: int = _p(50, "mains frequency", "Hz", choices=(50, 60))
    bowden_g_per_mm_x: float = _p(0.0, "bowden/umbilical force change per mm of X", "g/mm",
                                  minval=-1000.0, maxval=1000.0)
    bowden_g_per_mm_y: float = _p(0.0, "bowden/umbilical force change per mm of Y", "g/mm",
                                  minval=-1000.0, maxval=1000.0)
    bowden_g_per_mm_z: float = _p(0.0, "bowden/umbilical force change per mm of Z", "g/mm",
                                  minval=-1000.0, maxval=1000.0)
    thermal_drift_g_per_c: float = _p(0.2, "cell reading change per °C of cell warming", "g/°C",
                                      minval=-100.0, maxval=100.0)
    cell_heat_coupling: float = _p(0.1, "cell warms by this share of the nozzle's rise", "", minval=0.0, maxval=1.0)
    cell_heat_tau_s: float = _p(120.0, "cell warming time constant", "s", minval=1.0, maxval=100_000.0)
    # --- nozzle ---------------------------------------------------------------------------
    ambient_c: float = _p(25.0, "room and cold-nozzle temperature", "°C", minval=-50.0, maxval=100.0)
    heater_tau_s: float = _p(15.0, "nozzle heating time constant", "s", minval=0.1, maxval=10_000.0)
    bed_heater_tau_s: float = _p(60.0, "heated bed (and any other heater) time constant", "s", minval=0.1,
                                 maxval=10_000.0)
    nozzle_expansion_um_per_c: float = _p(0.45, "nozzle lengthens toward the bed per °C", "µm/°C",
                                          minval=-100.0, maxval=100.0)
    start_nozzle_c: float = _p(25.0, "nozzle temperature at power on", "°C", minval=-50.0, maxval=1000.0)
    ooze_film_um: float = _p(0.0, "initial ooze film on the nozzle tip", "µm", minval=0.0, maxval=1000.0)
    ooze_temp_c: float = _p(170.0, "filament starts to ooze above this nozzle temperature", "°C",
                            minval=0.0, maxval=1000.0)
    ooze_growth_um_per_s_per_c: float = _p(0.02, "film growth per second per °C above ooze_temp_c", "µm/s/°C",
                                           minval=0.0, maxval=100.0)
    ooze_max_um: float = _p(150.0, "thickest film that stays on the nozzle", "µm", minval=0.0, maxval=1000.0)
    ooze_stiffness_g_um: float = _p(1.2, "film stiffness when squeezed", "g/µm",
                                    minval=0.0, maxval=MAX_STIFFNESS_G_UM)
    ooze_squeeze_tau_s: float = _p(0.12, "time constant of the film flowing out under load", "s",
                                   minval=1e-3, maxval=1000.0)
    ooze_pull_g: float = _p(25.0, "largest pull of the film stretched on lift", "g", minval=0.0, maxval=10_000.0)
    # A strand is drawn from the film: its cross-section, and so the force it carries, shrinks with
    # the film (a 0.5 µm film holding 25 g over 40 µm would need ~150 MPa, beyond solid PETG).
    ooze_pull_full_um: float = _p(20.0, "film from which the strand pulls the full ooze_pull_g (thinner: "
                                  "in proportion)", "µm", minval=0.001, maxval=1000.0)
    ooze_break_um: float = _p(40.0, "stretch at which the film strand breaks", "µm", minval=0.1, maxval=10_000.0)
    ooze_clear_fraction: float = _p(0.4, "share of the film left on the bed at each tap", "", minval=0.0, maxval=1.0)
    ooze_residue_radius_mm: float = _p(0.5, "a tap this close to film left on the bed meets it first", "mm",
                                       minval=0.0, maxval=MAX_SIZE_MM)
    # --- calibration pin (XY probing; tapcell.sim.pin) ---------------------------------------
    pin_diameter_mm: float = _p(0.0, "calibration pin diameter; 0 = no pin", "mm", minval=0.0, maxval=100.0)
    pin_x_mm: float = _p(225.0, "calibration pin centre X", "mm", minval=-MAX_SIZE_MM, maxval=MAX_SIZE_MM)
    pin_y_mm: float = _p(225.0, "calibration pin centre Y", "mm", minval=-MAX_SIZE_MM, maxval=MAX_SIZE_MM)
    pin_height_mm: float = _p(5.0, "calibration pin height above the bed", "mm", minval=0.1, maxval=100.0)
    nozzle_tip_diameter_mm: float = _p(1.0, "outside diameter of the nozzle tip", "mm", minval=0.1, maxval=100.0)
    pin_side_stiffness_g_um: float = _p(4.0, "sideways stiffness of the toolhead against the pin", "g/µm",
                                        minval=0.01, maxval=MAX_STIFFNESS_G_UM)
    pin_side_coupling: float = _p(0.5, "share of a sideways force the load cell reads", "", minval=0.0, maxval=1.0)
    # --- scheduled sensor trouble ----------------------------------------------------------
    glitch_rate_per_s: float = _p(0.0, "random single corrupted frames per second", "1/s", minval=0.0, maxval=1000.0)
    disconnect_at_s: float = _p(-1.0, "the sensor stops delivering samples at this time; <0 = never", "s",
                                minval=-1.0, maxval=1e9)
    # --- virtual MCU ------------------------------------------------------------------------
    read_jitter_s: float = _p(15e-6, "mean extra delay of the MCU task reading a sample", "s", minval=0.0, maxval=1.0)
    stop_delay_s: float = _p(0.2e-3, "trigger to steppers stopped on the same MCU", "s", minval=0.0, maxval=1.0)
    multi_mcu_delay_s: float = _p(0.0, "extra stop delay when Z steppers are on another MCU", "s",
                                  minval=0.0, maxval=1.0)


PARAM_FIELDS = {f.name: f for f in fields(SimParams)}


class SimParamError(ValueError):
    """A virtual printer parameter has an unknown name or a value out of range."""

    def __init__(self, message: str, option: str | None = None):
        super().__init__(message)
        self.option = option


def check_params(params: SimParams) -> SimParams:
    """Validate ranges and choices; resolve chip-dependent defaults (sample rate, sheet values)."""
    for name, f in PARAM_FIELDS.items():
        value = getattr(params, name)
        meta = f.metadata
        if meta["choices"] is not None and value not in meta["choices"]:
            allowed = ", ".join(str(c) for c in meta["choices"])
            raise SimParamError(f"virtual printer parameter '{name}' = {value!r} is not one of: {allowed}", name)
        if meta["minval"] is not None and value < meta["minval"]:
            raise SimParamError(f"virtual printer parameter '{name}' = {value!r} is below the minimum {meta['minval']}", name)
        if meta["maxval"] is not None and value > meta["maxval"]:
            raise SimParamError(f"virtual printer parameter '{name}' = {value!r} is above the maximum {meta['maxval']}", name)
    rate = params.sample_rate_sps or CHIP_DEFAULT_RATE_SPS[params.chip]
    # An ADS131M0x's rates follow its clock (any clock_freq): the printer's config computed it.
    if rate not in CHIP_RATES_SPS[params.chip] and CHIP_RATES_SPS[params.chip] is not ADS131M0X_RATES_SPS:
        allowed = ", ".join(f"{r:g}" for r in sorted(set(CHIP_RATES_SPS[params.chip])))
        raise SimParamError(f"virtual printer parameter 'sample_rate_sps' = {rate:g} is not a {params.chip} rate; "
                            f"allowed: {allowed}", "sample_rate_sps")
    if params.gain not in CHIP_GAINS[params.chip]:
        allowed = ", ".join(str(g) for g in CHIP_GAINS[params.chip])
        raise SimParamError(f"virtual printer parameter 'gain' = {params.gain} is not a {params.chip} gain; "
                            f"allowed: {allowed}", "gain")
    if params.bed_shape == "csv" and not params.bed_csv:
        raise SimParamError("virtual printer parameter 'bed_csv' must name a CSV file when bed_shape is csv", "bed_csv")
    if params.z_position_min_mm >= params.z_position_max_mm:
        raise SimParamError("virtual printer parameter 'z_position_min_mm' must be below 'z_position_max_mm'", "z_position_min_mm")
    sheet = SHEETS[params.sheet]
    x_max = params.x_position_max_mm or params.bed_x_mm
    y_max = params.y_position_max_mm or params.bed_y_mm
    for axis, low, high, endstop in (("x", params.x_position_min_mm, x_max, params.x_endstop_mm),
                                     ("y", params.y_position_min_mm, y_max, params.y_endstop_mm)):
        if not low < high:
            raise SimParamError(f"virtual printer parameter '{axis}_position_min_mm' must be below "
                                f"'{axis}_position_max_mm'", f"{axis}_position_min_mm")
        if not low <= endstop <= high:
            raise SimParamError(f"virtual printer parameter '{axis}_endstop_mm' = {endstop:g} must be within "
                                f"{low:g}..{high:g}", f"{axis}_endstop_mm")
    return dataclasses.replace(
        params,
        x_position_max_mm=x_max,
        y_position_max_mm=y_max,
        sample_rate_sps=float(rate),
        sheet_stiffness_g_um=params.sheet_stiffness_g_um or sheet["stiffness_g_um"],
        contact_onset_um=params.contact_onset_um if params.contact_onset_um >= 0 else sheet["onset_um"],
    )


def make_params(overrides: dict) -> SimParams:
    """SimParams from name -> value overrides, with types coerced and every name checked."""
    coerced = {}
    for name, value in overrides.items():
        if name not in PARAM_FIELDS:
            raise SimParamError(f"unknown virtual printer parameter '{name}'; allowed: {', '.join(PARAM_FIELDS)}", name)
        kind = type(PARAM_FIELDS[name].default)
        try:
            coerced[name] = kind(value)
        except (TypeError, ValueError):
            raise SimParamError(f"virtual printer parameter '{name}' = {value!r} is not a {kind.__name__}", name) from None
    return check_params(SimParams(**coerced))


def series_stiffness_g_um(params: SimParams) -> float:
    """Frame, load cell and sheet act as springs in series."""
    return 1.0 / (1.0 / params.frame_stiffness_g_um + 1.0 / params.cell_stiffness_g_um
                  + 1.0 / params.sheet_stiffness_g_um)
