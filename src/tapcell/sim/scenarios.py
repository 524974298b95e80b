"""Named, documented scenarios: each is a short list of overrides on SimParams defaults."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    overrides: dict


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("clean", "well-built printer, HX717 at 320 sps, smooth PEI, cold clean nozzle", {}),
    Scenario("fast-adc", "ADS1220 in turbo mode at 660 sps (SPI, data-ready pin)",
             {"chip": "ads1220", "sample_rate_sps": 660.0, "white_noise_counts": 60.0}),
    Scenario("slow-adc", "HX711 at 80 sps with a 1.5 % fast oscillator; probe at <= 2 mm/s",
             {"chip": "hx711", "sample_rate_sps": 80.0, "chip_rate_error": 0.015, "white_noise_counts": 50.0}),
    Scenario("noisy-mains", "50 Hz hum coupled into the cell wiring, plus a noisier ground",
             {"hum_counts": 1500.0, "hum_hz": 50.0, "white_noise_counts": 160.0, "pink_noise_counts": 80.0}),
    Scenario("bowden-drift", "bowden tube and umbilical pull on the toolhead, changing with position",
             {"bowden_g_per_mm_x": 0.6, "bowden_g_per_mm_y": -0.4, "bowden_g_per_mm_z": -8.0,
              "pink_noise_counts": 120.0}),
    Scenario("soft-sheet", "soft textured sheet on a thin magnet: long nonlinear onset, low stiffness",
             {"sheet": "soft", "relax_fraction": 0.08, "hysteresis_fraction": 0.08}),
    Scenario("oozy", "nozzle at 210 °C with PETG ooze (film grows above 170 °C)",
             {"start_nozzle_c": 210.0, "ooze_film_um": 60.0, "ooze_temp_c": 170.0}),
    Scenario("glitchy", "long unshielded cable: random single corrupted frames (~1 per 2 s)",
             {"glitch_rate_per_s": 0.5}),
    Scenario("disconnected", "the ADC is not connected: no samples ever arrive",
             {"disconnect_at_s": 0.0}),
    Scenario("warped-bed", "bed bowed and saddled by smooth modes up to 0.25 mm",
             {"bed_shape": "warped", "bed_warp_mm": 0.25, "bed_warp_modes": 3}),
    Scenario("tilted-bed", "bed tilted 0.4 mm across X and -0.25 mm across Y",
             {"bed_shape": "tilted", "bed_tilt_x_mm": 0.4, "bed_tilt_y_mm": -0.25}),
)}
