"""StreamHealth: samples lost from the stamps, the window, episodes, the lag; the causes named (no ROS)."""

import math

from hypothesis import given, settings, strategies as st
import numpy as np

from ext_observer.nodes.stream_watch import StreamWatch
from ext_observer.pipeline.stream_health import (MAX_PENDING, MIN_INTERVALS, Report,
                                                 StreamHealth, THRESHOLD)

MS = 1_000_000
SECOND = 1_000_000_000
START = 1_700_000_000 * SECOND


def feed(health, stamps):
    for stamp in stamps:
        health.sample(int(stamp))


def test_a_whole_stream_loses_nothing():
    health = StreamHealth()
    feed(health, START + np.arange(1000) * MS)
    report = health.report(START + SECOND)
    assert report.received == 1000
    assert report.lost == report.lost_total == 0
    assert report.share == 0.0
    assert not report.warn and not report.started
    assert report.interval == 0.001
    assert report.longest_hole == 0.001
    assert math.isclose(report.lag, 0.001)


def test_a_hole_counts_its_missing_samples():
    health = StreamHealth()
    kept = np.concatenate([np.arange(400), np.arange(450, 1000)])  # 50 missing
    feed(health, START + kept * MS)
    report = health.report(START + SECOND)
    assert report.lost == 50
    assert report.received == 950
    assert math.isclose(report.share, 0.05)
    assert math.isclose(report.longest_hole, 0.051)
    assert report.warn and report.started


def test_random_losses_and_jitter():
    rng = np.random.default_rng(3)
    keep = rng.random(2000) > 0.05
    keep[:20] = True
    stamps = START + np.arange(2000) * MS + rng.integers(-100_000, 100_000, 2000)
    health = StreamHealth()
    feed(health, stamps[keep])
    report = health.report(START + 2 * SECOND)
    assert report.lost == int((~keep).sum())


def test_the_interval_is_learned_across_reports():
    health = StreamHealth()
    feed(health, START + np.arange(100) * 10 * MS)
    health.report(START + SECOND)
    # Fewer intervals than it takes to learn: the learned one counts the hole.
    feed(health, START + np.array([100, 101, 105]) * 10 * MS)
    report = health.report(START + 2 * SECOND)
    assert report.lost == 3
    assert report.interval == 0.01


def test_nothing_counted_before_the_interval_is_known():
    health = StreamHealth()
    feed(health, START + np.array([0, 1, 5]) * MS)
    report = health.report(START + SECOND)
    assert report.lost == 0
    assert math.isnan(report.interval)


def test_an_episode_starts_and_ends_once():
    health = StreamHealth(window=2.0)
    now, k = START, 0
    outcomes = []
    for second in range(8):
        stamps = np.arange(k, k + 1000)
        if second in (2, 3):
            stamps = stamps[stamps % 20 != 0]  # 5 % lost
        feed(health, START + stamps * MS)
        k += 1000
        now += SECOND
        report = health.report(now)
        outcomes.append((report.warn, report.started, report.ended))
    assert [o[1] for o in outcomes].count(True) == 1
    assert [o[2] for o in outcomes].count(True) == 1
    assert outcomes[2] == (True, True, False)
    assert outcomes[3] == (True, False, False)
    # The window (2 s) still holds the lossy second, then not.
    assert outcomes[4][0]
    assert outcomes[6] == (False, False, True) or outcomes[5] == (False, False, True)


def test_the_window_forgets_old_losses():
    health = StreamHealth(window=1.0)
    stamps = np.arange(1, 1000)
    feed(health, START + stamps[stamps % 4 != 0] * MS)
    feed(health, START + np.arange(1000, 1100) * MS)
    assert health.report(START + SECOND).share > 0.2
    feed(health, START + np.arange(1100, 3000) * MS)
    health.report(START + 2 * SECOND)
    report = health.report(START + 4 * SECOND)
    assert report.share == 0.0
    assert report.lost_total == 249


def test_a_clock_going_back_starts_a_new_window():
    health = StreamHealth()
    feed(health, START + np.arange(0, 100, 2) * MS)
    feed(health, START + np.arange(100, 200) * MS)
    health.report(START + SECOND)
    report = health.report(START)
    assert report.received == 0 and report.share == 0.0


def test_restart_forgets_everything():
    health = StreamHealth()
    feed(health, START + np.arange(0, 100, 3) * MS)
    feed(health, START + np.arange(100, 200) * MS)
    health.report(START + SECOND)
    health.restart()
    report = health.report(START + 2 * SECOND)
    assert report.lost_total == 0 and math.isnan(report.lag)


def test_pending_stamps_are_bounded():
    health = StreamHealth()
    feed(health, START + np.arange(MAX_PENDING + 10) * MS)
    assert health.report(START).received == MAX_PENDING


def test_stamps_going_back_are_no_losses():
    health = StreamHealth()
    stamps = list(START + np.arange(100) * MS) + [START, START + 100 * MS]
    feed(health, stamps)
    assert health.report(START + SECOND).lost == 0


@settings(max_examples=60, deadline=None)
@given(st.lists(st.booleans(), min_size=MIN_INTERVALS * 3, max_size=400),
       st.integers(1, 50))
def test_losses_counted_exactly_on_a_grid(kept, period_ms):
    # Whatever is removed from a regular stream (its first and last samples
    # and most of the rest kept), the count is exact.
    kept = [True] * (MIN_INTERVALS * 2 + 1) + kept + [True]
    stamps = [START + k * period_ms * MS for k, keep in enumerate(kept) if keep]
    health = StreamHealth()
    feed(health, stamps)
    report = health.report(START)
    missing = kept.count(False)
    intervals = np.diff(stamps)
    if np.median(intervals) == period_ms * MS:
        assert report.lost == missing
        assert report.share == (missing / len(kept) if missing else 0.0)
        assert report.warn == (report.share > THRESHOLD)
    assert report.lost <= missing


def report_with(lag, share=0.05):
    return Report(1000, 50, share, 50, 0.05, 0.05, 0.001, lag, True, True, False)


def test_the_likely_cause_names_what_to_do():
    watch = StreamWatch(None, 'IMU samples')
    watch.cpu_share = 0.2
    behind = watch.cause(report_with(0.2), 0)
    assert behind.startswith('the node falls behind its input (200 ms behind the stamps)')
    assert 'lower the IMU rate' in behind and 'raise queue_depth' in behind
    assert watch.cause(report_with(0.001), 7).startswith(
        'the node falls behind its input (7 lost in its queue)')
    before = watch.cause(report_with(0.001), 0)
    assert before.startswith('lost before they reach the node, which keeps up (1 ms behind')
    # Stamps from another clock: no lag to judge by.
    assert 'lag unknown' in watch.cause(report_with(3e6), 0)
    assert 'lag unknown' in watch.cause(report_with(-5.0), 0)
    watch.cpu_share = 0.95
    assert watch.cause(report_with(3e6), 0).startswith(
        'the node falls behind its input (95% of a core)')
