"""The virtual printer's memory of motion and samples is bounded in time (HISTORY_KEEP_S), so a
session of thousands of taps costs the same per tap (it grew +76 % CPU and +38 MB over 2,000
taps when every segment and sample was kept and scanned). The per-tap cost itself is a
benchmark number (bench/session_cost), not a timed test."""

import numpy as np
import pytest

from tapcell.extras.probe.approach import MAX_CONTACTS, BedHeightMemory
from tapcell.sim.mcu import SampleLog
from tapcell.sim.motion import FORGET_BATCH, HISTORY_KEEP_S, MotionHistory, Segment


def segment(t_s: float, z_mm: float) -> Segment:
    return Segment(t_s, 1.0, 1.0, 0.0, (0.0, 0.0, z_mm), (0.0, 0.0, 1.0))


def test_motion_history_keeps_its_horizon_and_answers_like_a_scan():
    history = MotionHistory((0.0, 0.0, 0.0))
    for second in range(3000):
        history.append([segment(float(second), float(second))])
    assert len(history.segments) <= HISTORY_KEEP_S + FORGET_BATCH + 1
    assert history.segments[-1].print_time == 2999.0
    for t0, t1 in ((2990.5, 2995.2), (2999.0, 3100.0), (2500.0, 2500.0)):
        scanned = [s for s in history.segments if s.end_time >= t0 and s.print_time <= t1]
        assert history.segments_between(t0, t1) == scanned
    assert history.positions_at(np.array([2995.5]))[0, 2] == pytest.approx(2995.5)
    history.replace_last(1, [segment(2999.0, 7.0)])
    assert history.end_position == (0.0, 0.0, 8.0)


def test_sample_log_keeps_its_horizon():
    log = SampleLog()
    for second in range(3000):
        t = second + np.arange(10) / 10.0
        log.append(t, np.arange(10, dtype=np.int32), np.zeros(10))
    t, counts, _ = log.between(2990.0, 2991.0)
    assert t.tolist() == pytest.approx([2990.0 + k / 10.0 for k in range(10)] + [2991.0])
    assert len(log.between(0.0, 3000.0)[0]) <= 10 * (HISTORY_KEEP_S + FORGET_BATCH + 1)


def test_the_probes_contact_memory_is_bounded():
    memory = BedHeightMemory(lambda x, y: None)
    for n in range(3 * MAX_CONTACTS):
        memory.remember(n, 0.0, 0.001 * n)
    assert len(memory.contacts_xyz_mm) == MAX_CONTACTS
    assert memory.expected_z_mm(3 * MAX_CONTACTS - 1, 0.0) == pytest.approx(0.001 * (3 * MAX_CONTACTS - 1))
