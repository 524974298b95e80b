"""Can one tap tell its contact's toe? What the toe model's bias is made of, per set (issue 21).

Three tables, each on taplab (this project's generator, seed 1) beside the reference taps:

1. **taplab's truth and its toe.** Clean taps whose toe the generator replaces (`dataclasses.replace`
   on the drawn spec, the generator's defaults untouched): as drawn, none (a hinge), a Hertzian
   toe, a parabolic one; with noise and noise-free. A noise-free hinge without the unloading loop's
   curvature or relaxation reads the generator's truth where the analysis reads contact (the
   force's return to zero on the way up) or it does not.
2. **The onset each set shows.** Per clean scenario, the pullback samples the analysis fitted,
   against the height below the truth: the linear region's zero (stiffness and baseline fitted 10-28
   µm deep and 5-40 µm above) lies `lift` below the truth: what a sharp contact reads low. Beside
   it the free air's scatter over the stiffness (µm: how far one sample's noise reaches) and the
   mean force at 1, 2 and 3 µm deep over the stiffness, with what a Hertzian (force ~ depth^1.5)
   and a parabolic toe of the same lift give there.
3. **What one tap can tell.** Noise-free, a toe of each set's median lift and each shape, sampled
   as the pullback samples it (1 µm a sample) and as the approach does (15 µm a sample, HX717 at
   5 mm/s; 2.5 µm with a 7.5 µm window, an ADS1220 at 2000 sps): the least residual of the other
   shape (stiffness, baseline, contact and width free), over the set's noise variance (Δχ²), with
   the contact it reads; and the same for a hinge. Δχ² well under 1 means no tap can tell them apart.

Run: .venv/bin/python -m bench toe_shape [--per-scenario N] [--reference PATH]
     (the reference taps default to ../shared/data/reference-taps.tar.xz from the repository root)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from tapcell.tap import AnalysisOptions, TapAnalysis, analyze_tap, read_tap_file
from tapcell.tap.readers import tap_from_object
from tapcell.tap.toe import toe_shape
from tapcell.taplab.benchmark import default_reference_archive, reference_set
from tapcell.taplab.generate import SCENARIOS, TapSpec, make_tap

HERTZ, PARABOLA = 0.5, 1.0  # stiffness ~ depth^power over the toe (tapcell.tap.toe.TOE_POWERS)
TAPLAB_CLEAN = ("clean_hx717", "clean_ads1220_660", "clean_ads1220_2000", "hx711_80", "latency", "soft_sheet")
REFERENCE_CLEAN = ("clean_hx717", "clean_ads1220_660", "clean_ads1220_2000", "hx711_slow", "latency", "soft_sheet")
DEEP_UM = (10.0, 28.0)  # the linear region's fit, µm below the truth
FREE_UM = (5.0, 40.0)  # free air, µm above the truth
PROFILE_DEPTHS_UM = (1.0, 2.0, 3.0)
REACH_UM = (30.0, 40.0)  # samples from this deep to this high around contact (table 3; the toe fit's reach)
WINDOW_POINTS = 8  # points per sample window for its average (table 3)
GEOMETRIES = (("pullback, 1 µm a sample", 1.0, 1.0), ("approach, 15 µm a sample", 15.0, 15.0),
              ("approach, 2.5 µm, 7.5 µm window", 2.5, 7.5))


def _quiet(spec: TapSpec) -> TapSpec:
    adc = dataclasses.replace(spec.adc, white_g=0.0, pink_g=0.0, jitter_s=0.0)
    return dataclasses.replace(spec, adc=adc, walk_g_per_sqrt_s=0.0, hum_g=(0.0, 0.0, 0.0), drift_g_per_mm=0.0)


def _toe(**changes) -> Callable[[TapSpec], TapSpec]:
    return lambda spec: dataclasses.replace(spec, contact=dataclasses.replace(spec.contact, **changes))


def _both(*edits: Callable[[TapSpec], TapSpec]) -> Callable[[TapSpec], TapSpec]:
    def edit(spec: TapSpec) -> TapSpec:
        for one in edits:
            spec = one(spec)
        return spec
    return edit


NO_TOE = _toe(onset_um=0.01)
TOE_VARIANTS = {
    "as drawn": lambda spec: spec,
    "none (hinge)": NO_TOE,
    "Hertzian": _toe(onset_power=HERTZ, onset_blend=0.0),
    "parabolic": _toe(onset_power=PARABOLA, onset_blend=0.0),
    "as drawn, noise-free": _quiet,
    "none, noise-free": _both(NO_TOE, _quiet),
    "none, no loop or relaxation, noise-free": _both(_toe(onset_um=0.01, unload_ratio=1.0, relax_fraction=(0.0,)),
                                                     _quiet),
}


def taplab_taps(name: str, count: int, seed: int = 1, edit: Callable[[TapSpec], TapSpec] | None = None):
    """(tap, truth mm) of a taplab scenario: the streams of `generate_set`, the spec edited first."""
    index = list(SCENARIOS).index(name)
    for k in range(count):
        rng = np.random.default_rng([seed, index + 1, k])
        spec = SCENARIOS[name].draw(rng)
        tap, truth = make_tap(edit(spec) if edit else spec, rng)
        yield tap_from_object(tap), float(truth["z_contact"])


def reference_taps(directory: Path, name: str):
    for line in (directory / "labels.jsonl").read_text(encoding="utf-8").splitlines():
        label = json.loads(line) if line.strip() else None
        if label and label["scenario"] == name:
            yield read_tap_file(directory / label["file"])[0], float(label["z_contact_mm"])


def _bias(taps: Iterable) -> str:
    errors = [(a.z_mm - truth) * 1000.0 for a, truth in ((analyze_tap(tap), truth) for tap, truth in taps)
              if a.valid and a.z_mm is not None]
    return f"{np.mean(errors):+.2f} ± {np.std(errors, ddof=1):.2f}" if len(errors) > 1 else "-"


@dataclasses.dataclass
class Onset:
    """One tap's pullback against the height below its truth (table 2)."""

    lift_um: float  # the linear region's zero lies this far below the truth
    noise_um: float  # the free air's scatter over the stiffness
    depth_um: np.ndarray  # per sample, below the truth (negative: above)
    force_over_k_um: np.ndarray  # per sample, baseline removed, over the stiffness


def onset_against_truth(analysis: TapAnalysis, truth_mm: float) -> Onset | None:
    """The pullback samples the analysis fitted (`pullback_fit`, window heights above the origin
    its toe fit read them from) against the height below the truth; None without them."""
    fit = analysis.pullback_fit
    if not analysis.valid or fit is None or analysis.toe_z_origin_mm is None:
        return None
    truth_um = (truth_mm - analysis.toe_z_origin_mm) * 1000.0
    depth = truth_um - (fit.x_min_um + 0.5 * fit.span_um)
    return onset_of(depth, fit.force_g)


def onset_of(depth_um: np.ndarray, force_g: np.ndarray) -> Onset | None:
    """`Onset` from samples' depth below the truth and force: free air (a line: the drift) and the
    linear region fitted apart."""
    free = (depth_um < -FREE_UM[0]) & (depth_um > -FREE_UM[1])
    deep = (depth_um > DEEP_UM[0]) & (depth_um < DEEP_UM[1])
    if np.count_nonzero(free) < 10 or np.count_nonzero(deep) < 5:
        return None
    drift, level = np.polyfit(depth_um[free], force_g[free], 1)
    above_air = force_g - (level + drift * depth_um)
    stiffness, at_truth = np.polyfit(depth_um[deep], above_air[deep], 1)
    if not stiffness > 0:
        return None
    scatter = float(np.std(above_air[free], ddof=2))
    return Onset(-at_truth / stiffness, scatter / stiffness, depth_um, above_air / stiffness)


def toe_force_over_k(depth_um: np.ndarray, lift_um: float, power: float) -> np.ndarray:
    """Force over stiffness of a toe of `power` whose linear region's zero lies lift_um deep (1-D)."""
    return toe_shape(np.atleast_1d(np.asarray(depth_um, dtype=float)), lift_um * (power + 1.0) / power, power)


def onset_row(onsets: list[Onset]) -> tuple[float, float, list[float]]:
    """(median lift, median noise over stiffness, mean profile at PROFILE_DEPTHS_UM)."""
    profile = []
    for depth in PROFILE_DEPTHS_UM:
        near = [o.force_over_k_um[np.abs(o.depth_um - depth) <= 0.5] for o in onsets]
        profile.append(float(np.mean(np.concatenate(near))))
    return (float(np.median([o.lift_um for o in onsets])), float(np.median([o.noise_um for o in onsets])), profile)


def window_mean(contact_um, width_um: float, power: float, starts_um: np.ndarray, span_um: float) -> np.ndarray:
    """A toe's force over stiffness averaged over each sample window [start, start + span] (µm above
    the contact's origin); contact_um may be an array (candidates, on a new first axis)."""
    points = starts_um[:, None] + span_um * (np.arange(WINDOW_POINTS) + 0.5) / WINDOW_POINTS
    depth = np.asarray(contact_um, dtype=float)[..., None, None] - points
    return toe_shape(depth, width_um, power).mean(axis=-1)


def _least_rss(y: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Least residual of y against each row of columns with a free scale and offset."""
    centred = columns - columns.mean(axis=-1, keepdims=True)
    yc = y - y.mean()
    cc = np.einsum("...n,...n->...", centred, centred)
    cy = centred @ yc
    return float(yc @ yc) - np.divide(cy * cy, cc, out=np.zeros_like(cc), where=cc > 0)


def best_other_toe(y: np.ndarray, starts_um: np.ndarray, span_um: float, power: float, widest_um: float
                   ) -> tuple[float, float]:
    """(least residual, its contact) of a toe of `power` fitted to y: contact and width on a grid,
    refined twice around the best; stiffness and baseline solved exactly. widest_um 0: a hinge."""
    contact_step, width_step = 0.05, widest_um / 40.0
    contacts = np.arange(-4.0, 4.0 + 1e-9, contact_step)
    widths = np.arange(0.0, widest_um + 1e-9, width_step) if widest_um > 0 else np.zeros(1)
    best = (np.inf, 0.0, 0.0)
    for _ in range(3):
        for width in widths:
            rss = _least_rss(y, window_mean(contacts, max(width, 0.0), power, starts_um, span_um))
            k = int(rss.argmin())
            if rss[k] < best[0]:
                best = (float(rss[k]), float(contacts[k]), float(width))
        contact_step, width_step = contact_step / 10.0, width_step / 10.0
        contacts = best[1] + np.arange(-10, 11) * contact_step
        widths = np.maximum(best[2] + np.arange(-10, 11) * width_step, 0.0) if widest_um > 0 else np.zeros(1)
    return best[0], best[1]


def identifiability(lift_um: float, power: float, other_power: float | None, spacing_um: float, span_um: float,
                    noise_um: float, phases: int = 4) -> tuple[float, float]:
    """Noise-free: a toe of `power` and lift_um at contact 0, sampled every spacing_um with windows
    span_um wide (at `phases` offsets of the sample clock), fitted with a toe of other_power (None:
    a hinge). (Δχ² at noise_um per sample, contact it reads), each the mean over the phases."""
    width = lift_um * (power + 1.0) / power
    found = []
    for phase in np.arange(phases) / phases:
        starts = np.arange(-REACH_UM[0] - phase * spacing_um, REACH_UM[1], spacing_um)
        y = window_mean(0.0, width, power, starts, span_um)
        found.append(best_other_toe(y, starts, span_um, other_power or HERTZ, 3.0 * width if other_power else 0.0))
    rss, contact = np.mean(found, axis=0)
    return float(rss / noise_um ** 2), float(contact)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench toe_shape", description=__doc__.split("\n\n")[0])
    parser.add_argument("--per-scenario", type=int, default=40, help="taplab taps per scenario (default 40)")
    parser.add_argument("--reference", metavar="PATH", help="the reference taps (archive or unpacked directory)")
    args = parser.parse_args(argv)
    count = args.per_scenario
    print("1. taplab (seed 1): the generator's toe replaced; tapcell analyze's defaults, bias ± sd µm")
    for name in ("clean_hx717", "clean_ads1220_660"):
        for variant, edit in TOE_VARIANTS.items():
            print(f"   {name:18s} {variant:42s} {_bias(taplab_taps(name, count, edit=edit))}")
    with tempfile.TemporaryDirectory(prefix="toe-shape-") as scratch:
        source = Path(args.reference) if args.reference else default_reference_archive()
        reference = reference_set(source, Path(scratch) / "reference") if source.exists() else None
        sets = {"taplab": [(n, taplab_taps(n, count)) for n in TAPLAB_CLEAN]}
        if reference is None:
            print(f"reference taps: {source} not found; left out")
        else:
            sets["reference"] = [(n, reference_taps(reference.directory, n)) for n in REFERENCE_CLEAN]
        print("\n2. the onset the taps show (µm): lift = the linear region's zero below the truth; noise = the "
              "free air's scatter / stiffness; force / stiffness at "
              + ", ".join(f"{d:g}" for d in PROFILE_DEPTHS_UM) + " µm deep (Hertzian | parabolic toe of that lift)")
        typical = {}
        for set_name, scenarios in sets.items():
            hard = []
            for name, taps in scenarios:
                onsets = [o for o in (onset_against_truth(analyze_tap(tap, AnalysisOptions()), truth)
                                      for tap, truth in taps) if o is not None]
                lift, noise, profile = onset_row(onsets)
                models = [toe_force_over_k(np.array(PROFILE_DEPTHS_UM), lift, p) for p in (HERTZ, PARABOLA)]
                shown = "  ".join(f"{v:.2f} ({h:.2f} | {q:.2f})" for v, h, q in zip(profile, *models))
                print(f"   {set_name:9s} {name:18s} {len(onsets):3d} taps  lift {lift:5.2f}  noise {noise:4.2f}  "
                      + shown)
                if name != "soft_sheet":
                    hard.extend(onsets)
            typical[set_name] = onset_row(hard)[:2]
    print("\n3. what one tap can tell, noise-free: Δχ² at the set's noise (clean scenarios' median) of the best "
          "toe of the other shape | of a hinge, and the contact each reads (µm)")
    for set_name, (lift, noise) in typical.items():
        for power, other in ((HERTZ, PARABOLA), (PARABOLA, HERTZ)):
            shape = "Hertzian" if power == HERTZ else "parabolic"
            for geometry, spacing, span in GEOMETRIES:
                shape_chi2, shape_contact = identifiability(lift, power, other, spacing, span, noise)
                hinge_chi2, hinge_contact = identifiability(lift, power, None, spacing, span, noise)
                print(f"   {set_name:9s} lift {lift:.2f} noise {noise:.2f}, {shape:9s} {geometry:32s} "
                      f"other shape {shape_chi2:6.3f} at {shape_contact:+.2f} | hinge {hinge_chi2:6.2f} "
                      f"at {hinge_contact:+.2f}")
    return 0
