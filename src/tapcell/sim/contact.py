"""Contact physics: the force between nozzle and bed, and the ooze film on the nozzle.

Sign convention: force_g > 0 pushes the nozzle up (compresses the load cell).
`gap_um` is how far the commanded nozzle tip is above the point of first touch
(negative = the commanded position is below it: the frame, cell and sheet are compressed).

Bed force model (per point on a uniform time grid):
* elastic: a smooth quadratic onset over `onset_um` then linear with the series stiffness
  of frame, load cell and sheet (`elastic_force_g`, continuous value and slope);
* hysteresis: a play variable s in [0, 1] follows the interference with `travel_um` of play;
  loading (s = 1) follows the elastic curve exactly, unloading (s = 0) is lower by `hysteresis_fraction`;
* stress relaxation: a Maxwell branch adds r/(1-r) of every sudden change, decaying with tau,
  so a sudden load relaxes by the fraction r during a long dwell and the stiffness of a
  steady press is exactly the elastic one.
Ooze film: a soft layer of `film_um` that touches first, flows out under load (squeeze),
and pulls the nozzle down when stretched on lift until the strand breaks, leaving part of
the film on the bed. What flows out and what the strand leaves stay on the bed where the
tap was (`ContactState.deposited_um`, placed as a residue spot by the printer).
It grows while the nozzle is above the filament's ooze temperature.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def elastic_force_g(interference_um, stiffness_g_um: float, onset_um: float):
    """Force for a given interference: 0 above the surface, quadratic onset, then linear."""
    d = np.maximum(np.asarray(interference_um, dtype=float), 0.0)
    if onset_um <= 0.0:
        return stiffness_g_um * d
    return np.where(d < onset_um, stiffness_g_um * d * d / (2.0 * onset_um),
                    stiffness_g_um * (d - 0.5 * onset_um))


@dataclass
class ContactModel:
    stiffness_g_um: float
    onset_um: float
    relax_fraction: float
    relax_tau_s: float
    hysteresis_fraction: float
    hysteresis_travel_um: float
    film_stiffness_g_um: float
    film_squeeze_tau_s: float
    film_pull_g: float
    film_pull_full_um: float  # the film from which the strand can pull film_pull_g (thinner: in proportion)
    film_break_um: float
    film_clear_fraction: float
    film_max_um: float


@dataclass
class ContactState:
    film_um: float = 0.0
    film_stuck: bool = False     # the film touched the bed in this contact and now holds on
    play_s: float = 1.0          # hysteresis play variable (1 = loading curve)
    relax_g: float = 0.0         # Maxwell-branch force
    last_interference_um: float = 0.0
    last_loaded_g: float = 0.0
    taps_cleared: int = 0        # strands broken (each leaves film on the bed)
    deposited_um: float = 0.0    # film left on the bed by broken strands, not yet placed as residue


def contact_forces(gap_um: np.ndarray, dt_s: float, growth_um: np.ndarray, model: ContactModel,
                   state: ContactState) -> tuple[np.ndarray, np.ndarray]:
    """Bed and film force at each grid point; `state` is advanced in place.

    growth_um: film growth during each step (from nozzle temperature). Points far from
    any contact are handled with array operations; only near-contact points loop.
    """
    n = gap_um.size
    bed_g = np.zeros(n)
    film_g = np.zeros(n)
    film_upper = min(state.film_um + float(np.sum(growth_um)), model.film_max_um)
    reach_um = film_upper + (model.film_break_um if film_upper > 0.0 else 0.0)
    if n == 0:
        return bed_g, film_g
    if not np.any(gap_um < reach_um):
        if state.film_stuck:
            _break_strand(state, model)
        state.play_s, state.relax_g, state.last_interference_um, state.last_loaded_g = 1.0, 0.0, 0.0, 0.0
        state.film_um = min(state.film_um + float(np.sum(growth_um)), model.film_max_um)
        return bed_g, film_g

    k = model.stiffness_g_um
    onset = model.onset_um
    relax_gain = model.relax_fraction / (1.0 - model.relax_fraction)
    relax_decay = math.exp(-dt_s / model.relax_tau_s)
    squeeze_keep = math.exp(-dt_s / model.film_squeeze_tau_s)
    hyst = model.hysteresis_fraction
    travel = model.hysteresis_travel_um
    s, relax, last_d, last_loaded = state.play_s, state.relax_g, state.last_interference_um, state.last_loaded_g
    film, stuck = state.film_um, state.film_stuck
    for i in range(n):
        g = float(gap_um[i])
        if g < 0.0:
            d = -g
            elastic = k * d * d / (2.0 * onset) if d < onset else k * (d - 0.5 * onset)
            s = min(1.0, max(0.0, s + (d - last_d) / travel))
            loaded = elastic * (1.0 - hyst * (1.0 - s))
            relax = relax * relax_decay + relax_gain * (loaded - last_loaded)
            bed_g[i] = max(loaded + relax, 0.0)
            last_d, last_loaded = d, loaded
        else:
            s, relax, last_d, last_loaded = 1.0, 0.0, 0.0, 0.0
        if film > 0.0:
            room = max(g, 0.0)
            squeeze = film - room
            if squeeze > 0.0:
                film_g[i] = model.film_stiffness_g_um * squeeze
                flowed_out = squeeze * (1.0 - squeeze_keep)   # pushed aside onto the bed
                film -= flowed_out
                state.deposited_um += flowed_out
                stuck = True
            elif stuck:
                stretch = -squeeze
                if stretch < model.film_break_um:
                    most_g = model.film_pull_g * min(1.0, film / model.film_pull_full_um)
                    film_g[i] = -min(model.film_stiffness_g_um * stretch, most_g)
                else:
                    state.film_um = film
                    _break_strand(state, model)
                    film, stuck = state.film_um, False
        film = min(film + float(growth_um[i]), model.film_max_um)
    state.play_s, state.relax_g, state.last_interference_um, state.last_loaded_g = s, relax, last_d, last_loaded
    state.film_um, state.film_stuck = film, stuck
    return bed_g, film_g


def _break_strand(state: ContactState, model: ContactModel) -> None:
    state.deposited_um += state.film_um * model.film_clear_fraction
    state.film_um *= 1.0 - model.film_clear_fraction
    state.film_stuck = False
    state.taps_cleared += 1
