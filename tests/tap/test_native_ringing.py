"""The dwell's ringing in C (tapcell.tap._c_ringing) against its numpy twin (tapcell.tap.stage.dwell_ringing).

The kernel fits the same quadratic (its sums in another order) and evaluates the same 2n + 1 bins of
the residual's length-4n DFT by another FFT (Bluestein's chirp over power-of-two FFTs, where numpy
runs pocketfft): the powers agree to rounding, the bin and so the period bit for bit. Measured over
the 1,113 dwells the analysis of taplab seed 1 and the 960 reference taps looks at: powers within
9.3e-14 relative, the same bin and the same None every time (the 885 dwells of bench tap_sweep's
cases, its 4000 sps ringings among them: within 5.3e-13); the tolerance is ten times the first.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from native_kernel_inputs import OPTIONS, generated_taps, recorded_calls, scalar_build
from tapcell.tap import analysis, stage

pytestmark = pytest.mark.skipif(stage._C_RINGING is None, reason="the ringing kernel is not built (TAPCELL_NATIVE=0)")

RELATIVE = 1e-12


def twin(monkeypatch, *args):
    with monkeypatch.context() as patch:
        patch.setattr(stage, "_C_RINGING", None)
        return stage.dwell_ringing(*args)


def assert_agree(found, reference):
    assert (found is None) == (reference is None)
    if found is not None:
        assert found.period_samples == reference.period_samples  # the same bin: the same arithmetic after it
        assert found.var_g2 == pytest.approx(reference.var_g2, rel=RELATIVE, abs=0)


def test_the_kernel_finds_what_the_twin_finds_on_taplabs_dwells(monkeypatch):
    # Every scenario, the ringing gantry and the 2000 sps ADS1220 among them: dwells of 10-600 samples.
    taps = generated_taps(4, 5)
    calls = recorded_calls(analysis, "dwell_ringing", [OPTIONS["default"]], taps)
    assert len(calls) >= 40
    lengths = [len(force) for _, force, _ in calls]
    assert min(lengths) < stage.RINGING_MIN_SAMPLES and max(lengths) > 300
    found = 0
    for call in calls:
        ringing = stage.dwell_ringing(*call)
        assert_agree(ringing, twin(monkeypatch, *call))
        found += ringing is not None
    assert found >= 5  # the comparison covers ringings found, not only None


def _white_dwell(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """n samples at 1000 sps with a small jitter in time, white noise on 80 g."""
    rng = np.random.default_rng([seed, n])
    t = np.arange(n) / 1000.0 + rng.uniform(-1e-5, 1e-5, n)
    return t, 80.0 + rng.normal(0.0, 1.0, n)


@pytest.mark.parametrize("lengths", [range(16, 200), range(200, 420, 7), (509, 512, 601, 797, 800, 1009, 1500)],
                         ids=("16-199", "200-419", "long and prime"))
def test_the_largest_bin_is_the_twins_at_every_length(monkeypatch, lengths):
    # White noise is where bins come closest to a tie; with no threshold the largest bin is always
    # returned, so every length (prime ones too: pocketfft's slow case, the kernel's Bluestein sizes
    # 2^k either side of 2.5 n) compares the argmax itself.
    monkeypatch.setattr(stage, "RINGING_MIN_CHI2", 0.0)
    for n in lengths:
        t, force = _white_dwell(n, 1)
        found = stage.dwell_ringing(t, force, 1.0)
        assert found is not None, n
        assert_agree(found, twin(monkeypatch, t, force, 1.0))


def test_a_ringing_on_a_bin_is_found_at_its_period_and_power():
    # 40 Hz at 4000 sps over 400 samples: 4 periods, bin 16 of the 1600-point padded DFT. The power
    # there, worked out another way (lstsq's quadratic, the DFT at 40 Hz as a plain sum): 3 g's
    # a^2/2 = 4.5 g^2 less what the quadratic takes of 4 periods, 4.16.
    n = 400
    t = np.arange(n) / 4000.0
    force = 80.0 - 2.0 * t / t[-1] + 0.5 * (t / t[-1]) ** 2 + 3.0 * np.sin(2.0 * math.pi * 40.0 * t)
    u = (t - t.mean()) / (t[-1] - t[0])
    basis = np.array((np.ones(n), u, u * u)).T
    residual = force - basis @ np.linalg.lstsq(basis, force, rcond=None)[0]
    expected_g2 = 2.0 * abs((residual * np.exp(-2j * math.pi * 40.0 * t)).sum()) ** 2 / n / n
    ringing = stage.dwell_ringing(t, force, 0.01)
    assert ringing is not None
    assert ringing.period_samples == pytest.approx(100.0, rel=1e-12)
    assert expected_g2 == pytest.approx(4.16, abs=0.01)
    assert ringing.var_g2 == pytest.approx(expected_g2, rel=1e-9)


def test_the_end_bins_are_the_twins(monkeypatch):
    # The bins the spectrum's unpacking reads at its ends: k = 2n (the Nyquist rate, which reads Z_0
    # beside Z_L's mirror) and, from no lowest period, k = 0 (Z_0 and its own mirror). An alternating
    # force rings at the Nyquist rate: period 2 samples, the last bin. From bin 0 on, the largest bin
    # is the twin's at lengths either side of the FFT sizes (bin 0 itself holds the residual's sum,
    # which the quadratic's level leaves at rounding: it takes part, it never wins).
    n = 101
    t = np.arange(n) / 1000.0
    force = 80.0 + 0.5 * (-1.0) ** np.arange(n)
    ringing = stage.dwell_ringing(t, force, 0.01)
    assert ringing is not None and ringing.period_samples == pytest.approx(2.0, rel=1e-12)
    assert_agree(ringing, twin(monkeypatch, t, force, 0.01))
    monkeypatch.setattr(stage, "RINGING_MIN_PERIODS", 0.0)
    monkeypatch.setattr(stage, "RINGING_MIN_CHI2", 0.0)
    for n in (16, 17, 40, 51, 102, 103, 104):
        t, force = _white_dwell(n, 2)
        found = stage.dwell_ringing(t, force, 1.0)
        assert found is not None, n
        assert_agree(found, twin(monkeypatch, t, force, 1.0))


@pytest.mark.parametrize("case", ["too few", "no noise", "negative noise", "zero span", "time running back",
                                  "a quadratic", "a constant", "too many periods asked"])
def test_what_shows_no_ringing_is_none_in_both(monkeypatch, case):
    n = 120
    t = np.arange(n) / 2000.0
    force = 80.0 + 5.0 * np.sin(2.0 * math.pi * 100.0 * t)  # 6 periods: a ringing where the case allows it
    noise, periods = 0.05, stage.RINGING_MIN_PERIODS
    if case == "too few":
        t, force = t[:stage.RINGING_MIN_SAMPLES - 1], force[:stage.RINGING_MIN_SAMPLES - 1]
    elif case == "no noise":
        noise = 0.0
    elif case == "negative noise":
        noise = -1.0
    elif case == "zero span":
        t = np.full(n, 0.5)
    elif case == "time running back":
        t = t[::-1].copy()
    elif case == "a quadratic":
        force = 80.0 + 3.0 * t - 40.0 * t * t
    elif case == "a constant":
        force = np.full(n, 80.0)
    else:  # from half the samples' count of periods up: above the Nyquist rate's 2n bins
        periods = n / 2 + 1.0
    if case == "too many periods asked":
        assert twin(monkeypatch, t, force, noise) is not None  # the sine rings at the default's periods
    monkeypatch.setattr(stage, "RINGING_MIN_PERIODS", periods)
    assert stage.dwell_ringing(t, force, noise) is None
    assert twin(monkeypatch, t, force, noise) is None


def test_bad_arrays_are_errors_not_garbage():
    t = np.arange(40) / 1000.0
    with pytest.raises(ValueError, match="time_s: 39 values, 40 expected"):
        stage._C_RINGING.dwell_ringing(t[:39], np.zeros(40), 1.0, 16, 3.5, 25.0)
    with pytest.raises(TypeError, match="float64"):
        stage._C_RINGING.dwell_ringing(t, np.zeros(40, dtype=np.int64), 1.0, 16, 3.5, 25.0)


@pytest.fixture(scope="module")
def scalar_ringing(tmp_path_factory):
    """c/ringing.c built with -DTAPCELL_SCALAR (the FFTs' plain complex arithmetic), beside the installed kernel."""
    return scalar_build("ringing", tmp_path_factory.mktemp("scalar_ringing"))


def test_the_scalar_build_gives_the_vector_ffts_bits(scalar_ringing, monkeypatch):
    # The SSE2 butterflies hold a complex number in one vector, each lane's operations the plain
    # code's: every power and period bit for bit, on taplab's dwells (10-600 samples, the FFTs of
    # 16-4096 points, odd and even stage counts) and on white noise at lengths either side of powers of two.
    calls = recorded_calls(analysis, "dwell_ringing", [OPTIONS["default"]], generated_taps(4, 5))
    calls += [(*_white_dwell(n, 3), 1.0) for n in (16, 17, 31, 64, 100, 129, 255, 256, 700)]
    vector = [stage.dwell_ringing(*call) for call in calls]
    # The largest bin of every dwell, with no threshold to turn it into None.
    vector_bins = [stage._C_RINGING.dwell_ringing(*call, 2, 0.0, 0.0) for call in calls]
    monkeypatch.setattr(stage, "_C_RINGING", scalar_ringing)
    assert vector == [stage.dwell_ringing(*call) for call in calls]
    assert vector_bins == [scalar_ringing.dwell_ringing(*call, 2, 0.0, 0.0) for call in calls]
    assert sum(found is not None for found in vector) >= 5  # ringings found, not only None
    assert sum(found is not None for found in vector_bins) >= len(calls) - 10


def test_a_kept_chirp_filter_gives_a_later_dwell_of_its_length_the_same_bits(scalar_ringing, monkeypatch):
    # The chirp filter of a length is made on its first dwell and kept (up to 4096 samples): a later
    # dwell of that length must find the bits it would find first, and the first dwell again its own.
    # The scalar build is loaded fresh in this module, so 2749 samples (no other test's length) is a
    # first call there; 4099 is past the lengths kept, made and freed every call, and grows the twiddle
    # table after 2749's filter was kept: 2749 again must still give its first bits.
    monkeypatch.setattr(stage, "RINGING_MIN_CHI2", 0.0)
    args = (stage.RINGING_MIN_SAMPLES, stage.RINGING_MIN_PERIODS, 0.0)
    first_found = {}
    for n in (2749, 4099):
        (t, first), (_, second) = _white_dwell(n, 4), _white_dwell(n, 5)
        made = first_found[n] = scalar_ringing.dwell_ringing(t, first, 1.0, *args)
        other = scalar_ringing.dwell_ringing(t, second, 1.0, *args)
        assert made is not None and other is not None and made != other
        assert scalar_ringing.dwell_ringing(t, first, 1.0, *args) == made
        assert scalar_ringing.dwell_ringing(t, second, 1.0, *args) == other
        assert stage._C_RINGING.dwell_ringing(t, first, 1.0, *args) == made  # the vector build's, kept or not
        assert_agree(stage.Ringing(*made), twin(monkeypatch, t, first, 1.0))
    t, first = _white_dwell(2749, 4)
    assert scalar_ringing.dwell_ringing(t, first, 1.0, *args) == first_found[2749]
