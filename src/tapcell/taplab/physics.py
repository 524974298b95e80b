"""Contact physics of the independent tap generator (numpy only).

Written apart from the virtual printer (`tapcell.sim`) and from the analysis' own synthetic taps
(`tapcell.tap.synth`): its own parameterisation, so the analysis is scored on physics it was not
written against. Everything is a function of the *commanded overtravel* x (µm): how far the
commanded nozzle position is below the height at which it just touches the bare bed. The frame,
the load cell and the bed are springs in series; x folds them together.

* Loading: a nonlinear first touch over `onset_um` (stiffness rising as a blend of a power law
  and a smoothstep, so neither the analysis' parabola nor plain Hertz), C1 into the linear region.
* Unloading from the deepest point: a loop in force space, F_u = F_l·(1 + (q − 1)(F_l − F_peak)/F_peak)
  with q the unloading/loading slope ratio at the peak: the toe keeps its shape scaled by 2 − q,
  and the loop still reaches zero force exactly at x = 0.
* Stress relaxation: the elastic force times (1 − r(t)), r rising towards a few per cent with
  50–300 ms time constants from the first touch on, through the dwell and the decompression.
* Ooze: a bead hanging under the nozzle gives a viscous force while it is squeezed (before the
  solid touch, proportional to the closing speed), a film between nozzle and bed that squeezes
  out during the dwell (the force drops) but leaves a residual (the nozzle leaves the film, above
  the bed), and a plastic thread pulling on the nozzle after break contact, decaying with height.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Contact:
    stiffness_g_um: float  # slope of the linear region, frame + cell + bed in series
    onset_um: float  # width of the nonlinear first touch
    onset_power: float  # stiffness ~ (x/onset)^power near the touch (0.5: Hertz sphere on flat)
    onset_blend: float  # 0..1: share of a smoothstep stiffness ramp mixed into the power law
    unload_ratio: float  # unloading slope / loading slope at the deepest point
    relax_fraction: tuple[float, ...]  # per relaxation branch, share of the force it relaxes
    relax_tau_s: tuple[float, ...]  # per branch, its time constant
    # A two-stage mount (a magnetic sheet, a sprung bed): a soft first stage of this travel and
    # stiffness from the first touch, then the contact above (its toe and linear region). 0: none.
    stage_um: float = 0.0
    stage_stiffness_g_um: float = 0.0


@dataclass(frozen=True)
class Ooze:
    bead_um: float  # how far the molten bead hangs below the nozzle tip
    viscous_g_per_mm_s: float  # squeeze force per mm/s of closing speed, bead fully squeezed
    film_um: float  # film left between nozzle and bed at the solid touch
    film_residual_um: float  # what the dwell cannot squeeze out
    squeeze_tau_s: float  # film squeeze-out time constant at 100 g
    thread_g: float  # peak pull of the plastic thread after break contact
    thread_length_um: float  # height over which the pull rises and decays


def onset_stiffness_fraction(u: np.ndarray, contact: Contact) -> np.ndarray:
    """Stiffness / linear stiffness at u = x / onset, for 0 <= u <= 1 (0 at the touch, 1 at u = 1)."""
    smooth = u * u * (3.0 - 2.0 * u)
    return (1.0 - contact.onset_blend) * u ** contact.onset_power + contact.onset_blend * smooth


def _onset_integral(u: np.ndarray, contact: Contact) -> np.ndarray:
    """∫0^u of onset_stiffness_fraction (closed form), for 0 <= u <= 1."""
    p = contact.onset_power
    smooth = u ** 3 - 0.5 * u ** 4
    return (1.0 - contact.onset_blend) * u ** (p + 1.0) / (p + 1.0) + contact.onset_blend * smooth


def loading_force_g(x_um: np.ndarray, contact: Contact) -> np.ndarray:
    """Elastic force while pressing in (g) at overtravel x (µm); 0 above the bed. A two-stage
    mount first gives stage_stiffness over stage_um, then the contact proper from there on."""
    x_um = np.asarray(x_um, dtype=float)
    if contact.stage_um > 0:
        first = contact.stage_stiffness_g_um * np.clip(x_um, 0.0, contact.stage_um)
        return first + _contact_loading_g(x_um - contact.stage_um, contact)
    return _contact_loading_g(x_um, contact)


def _contact_loading_g(x_um: np.ndarray, contact: Contact) -> np.ndarray:
    w = contact.onset_um
    u = np.clip(x_um / w, 0.0, 1.0)
    inside = contact.stiffness_g_um * w * _onset_integral(u, contact)
    beyond = np.maximum(x_um - w, 0.0) * contact.stiffness_g_um
    return inside + beyond


def elastic_force_g(x_um: np.ndarray, contact: Contact) -> np.ndarray:
    """Elastic force along a path of overtravel samples: loading while x is at its running maximum,
    the unloading curve from that maximum otherwise (zero force exactly at x = 0 either way)."""
    x_um = np.asarray(x_um, dtype=float)
    deepest = np.maximum.accumulate(x_um)
    loaded = loading_force_g(x_um, contact)
    peak = loading_force_g(deepest, contact)
    # The loop in force space: F_u = F_l (1 + (q - 1)(F_l - F_peak)/F_peak). Slope q × loading at the
    # peak, (2 - q) × loading near zero force, monotonic, and zero exactly where loading is zero.
    with np.errstate(divide="ignore", invalid="ignore"):
        unloading = loaded * (1.0 + (contact.unload_ratio - 1.0) * np.where(peak > 0, (loaded - peak) / peak, 0.0))
    return np.where(x_um >= deepest, loaded, unloading)


def relaxed_share(t_s: np.ndarray, touch_s: float, contact: Contact) -> np.ndarray:
    """r(t): the share of the elastic force relaxed away, from the first touch on."""
    age = np.maximum(np.asarray(t_s, dtype=float) - touch_s, 0.0)
    share = np.zeros_like(age)
    for fraction, tau_s in zip(contact.relax_fraction, contact.relax_tau_s):
        share += fraction * -np.expm1(-age / tau_s)
    return share


def squeeze_profile_g(gap_um: np.ndarray, ooze: Ooze) -> np.ndarray:
    """0..1: how much of the bead is squeezed at a nozzle-to-film gap (1 at contact)."""
    squeezed = np.clip((ooze.bead_um - np.asarray(gap_um, dtype=float)) / ooze.bead_um, 0.0, 1.0)
    return squeezed * squeezed


def thread_pull_g(rise_um: np.ndarray, ooze: Ooze) -> np.ndarray:
    """Pull of the plastic thread (g, towards the bed) at a height above where the nozzle left the film."""
    s = np.maximum(np.asarray(rise_um, dtype=float), 0.0) / ooze.thread_length_um
    return ooze.thread_g * s * np.exp(1.0 - s)


def contact_force_g(t_s: np.ndarray, overtravel_um: np.ndarray, closing_mm_s: np.ndarray, pulling_back: np.ndarray,
                    contact: Contact, ooze: Ooze | None,
                    touch_s: float | None = None) -> tuple[np.ndarray, dict[str, float]]:
    """Force on the nozzle (g, positive pressing up) along a fine time grid, and facts for the truth.

    overtravel_um: commanded overtravel below the bare bed; closing_mm_s: speed towards the bed
    (negative while lifting); pulling_back: True from the pullback's start on. touch_s: when the
    relaxation starts; by default the first grid time that touches (the generator), given exactly
    where the force must be smooth in the contact height (`taplab.bound`'s derivatives).
    """
    film_um = np.zeros_like(t_s)
    if ooze is not None:
        film_um[:] = ooze.film_um
        # The film squeezes out while pressed: d(film)/dt = -(film - residual) * force / (100 g * tau).
        # The force itself depends on the film; two passes of a fixed point are plenty here.
        for _ in range(2):
            through_film = elastic_force_g(overtravel_um + film_um, contact)
            impulse = np.concatenate(([0.0], np.cumsum(0.5 * (through_film[1:] + through_film[:-1]) * np.diff(t_s))))
            film_um = ooze.film_residual_um + (ooze.film_um - ooze.film_residual_um) * np.exp(
                -impulse / (100.0 * ooze.squeeze_tau_s))
        # The film never grows back once squeezed (the nozzle leaves it behind).
        film_um = np.minimum.accumulate(film_um)
    effective_um = overtravel_um + film_um
    touching = effective_um > 0.0
    # Heavy ooze can stop the nozzle on the bead before it ever touches the bed through the film.
    if touch_s is None:
        touch_s = float(t_s[np.argmax(touching)]) if touching.any() else float("inf")
    elastic = elastic_force_g(effective_um, contact) * (1.0 - relaxed_share(t_s, touch_s, contact))
    facts = {"touch_time_s": touch_s, "film_left_um": float(film_um[-1])}
    if ooze is None:
        return elastic, facts
    gap_um = -effective_um
    viscous = ooze.viscous_g_per_mm_s * closing_mm_s * np.where(touching, 1.0, squeeze_profile_g(gap_um, ooze))
    # The thread pulls from where the nozzle left the film on the way up.
    left = pulling_back & ~touching
    thread = np.zeros_like(t_s)
    if left.any():
        thread[left] = thread_pull_g(gap_um[left], ooze)
    return elastic + viscous - thread, facts
