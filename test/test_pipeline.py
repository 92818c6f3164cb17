"""The ROS-free input path: stamp-ordered merge, stamp guard, loss detection, feeder, load."""
from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from online_em_slam.core.config import SlamConfig
from online_em_slam.core.filter.slam import OnlineEMSlam
from online_em_slam.core.types import Observations
from online_em_slam.pipeline import (CONTROL, OBSERVATIONS, ODOMETRY, TIE_ORDER, Feeder, Input, InputPath,
                                     InputPipeline, LoadMonitor, Sequencer, StampGuard, inputs)
from online_em_slam.pipeline.gaps import GapDetector

EMPTY = Observations(np.zeros(0), np.zeros(0), np.zeros(0, dtype=np.int64))


def obs(*ranges):
    n = len(ranges)
    return Observations(np.asarray(ranges, float), np.zeros(n), np.full(n, -1, dtype=np.int64))


def streams(rng, duration=5.0):
    """Odometry at 40 Hz and clouds at ~4.7 Hz (some stamps shared with odometry), each in stamp order."""
    odometry = [(ODOMETRY, round(0.025 * k, 6), k) for k in range(int(duration / 0.025))]
    clouds = [(OBSERVATIONS, round(0.2 * k + (0.0 if k % 3 else 0.05), 6), -k) for k in range(int(duration / 0.2))]
    return odometry, clouds


def interleave(rng, a, b):
    out, i, j = [], 0, 0
    while i < len(a) or j < len(b):
        if j >= len(b) or (i < len(a) and rng.random() < 0.5):
            out.append(a[i])
            i += 1
        else:
            out.append(b[j])
            j += 1
    return out


def run_sequencer(events, silence=math.inf):
    seq = Sequencer((ODOMETRY, OBSERVATIONS), silence)
    out = []
    for kind, stamp, payload in events:
        out += seq.push(Input(stamp, kind, payload=payload), 0.0)
    return [(i.stamp, i.kind, i.payload) for i in out + seq.flush()], seq.drops


def test_merge_is_the_same_for_every_interleaving():
    rng = np.random.default_rng(0)
    odometry, clouds = streams(rng)
    expected = sorted(odometry + clouds, key=lambda e: (e[1], e[0]))
    expected = [(stamp, kind, payload) for kind, stamp, payload in expected]
    for _ in range(20):
        got, drops = run_sequencer(interleave(rng, odometry, clouds))
        assert got == expected and not drops
    # Tie rule: odometry before observations at one stamp, control after them.
    seq = Sequencer((ODOMETRY, OBSERVATIONS, CONTROL), math.inf)
    out = []
    for item in (Input(1.0, CONTROL), Input(1.0, OBSERVATIONS, payload=EMPTY), Input(1.0, ODOMETRY)):
        out += seq.push(item, 0.0)
    assert [i.kind for i in out + seq.flush()] == [ODOMETRY, OBSERVATIONS, CONTROL]


def test_watermark_waits_for_every_live_stream_and_empty_clouds_advance_it():
    seq = Sequencer((ODOMETRY, OBSERVATIONS), silence=1.0)
    assert seq.push(Input(0.0, ODOMETRY), wall=0.0) == []            # observations not heard yet
    assert [i.stamp for i in seq.push(Input(0.0, OBSERVATIONS, payload=EMPTY), 0.01)] == [0.0, 0.0]
    for k in range(1, 9):
        assert seq.push(Input(0.025 * k, ODOMETRY), 0.01 + 0.025 * k) == []   # held for the cloud stream
    released = seq.push(Input(0.2, OBSERVATIONS, payload=EMPTY), 0.25)      # an empty cloud releases them
    assert [i.stamp for i in released] == pytest.approx([0.025 * k for k in range(1, 9)] + [0.2])


def test_silent_stream_stops_holding_and_a_lagging_stream_is_still_in_time():
    """A detector delivering 60 ms late, silent for longer than ``silence``, is not dropped when it
    resumes, even 90 ms late (the executor's order on a loaded machine adds to the latency)."""
    seq = Sequencer((ODOMETRY, OBSERVATIONS), silence=1.0)
    wall = lambda stamp: stamp + 0.001          # noqa: E731  odometry arrives at once
    out = []
    t = 0.0
    for k in range(200):                        # 5 s of odometry; clouds 60 ms late for the first second
        t = 0.025 * k
        out += seq.push(Input(t, ODOMETRY), wall(t))
        if k % 8 == 0 and t < 1.0:
            out += seq.push(Input(t - 0.06, OBSERVATIONS, payload=obs(5.0)), wall(t))
        out += seq.release(wall(t))
    assert out and out[-1].stamp > 3.5          # the silent stream stopped holding odometry back
    for k in range(200, 240):                   # the detector resumes, 90 ms late
        t = 0.025 * k
        out += seq.push(Input(t, ODOMETRY), wall(t))
        if k % 8 == 0:
            out += seq.push(Input(t - 0.09, OBSERVATIONS, payload=obs(5.0)), wall(t))
    out += seq.flush()
    assert not seq.drops, seq.drops
    assert sum(i.kind == OBSERVATIONS for i in out) == 5 + 5
    assert [i.stamp for i in out] == sorted(i.stamp for i in out)


def test_out_of_order_repeated_and_late_inputs_are_counted():
    seq = Sequencer((ODOMETRY, OBSERVATIONS), silence=0.0)
    seq.push(Input(1.0, ODOMETRY), 0.0)
    seq.push(Input(1.0, ODOMETRY), 0.0)
    seq.push(Input(0.5, ODOMETRY), 0.0)
    seq.push(Input(2.0, OBSERVATIONS, payload=obs(1.0)), 0.0)
    seq.push(Input(2.0, OBSERVATIONS, payload=obs(1.0)), 0.0)
    seq.push(Input(1.5, ODOMETRY), 0.0)                     # behind what was released
    assert seq.drops == Counter(zero_time_step=1, out_of_order=2, repeated_stamp=1)


@pytest.mark.parametrize("bad", [0.0, -5.0, 1e6, 2.0 ** 31 - 1])
def test_a_lone_bad_stamp_is_dropped_and_does_not_move_the_time_line(bad):
    path = InputPath((ODOMETRY, OBSERVATIONS), silence=0.0, jump_threshold=1.0)
    released = []
    for k in range(40):
        t = 1000.0 + 0.025 * k
        stamp = bad if k == 20 else t
        pushed = path.push(ODOMETRY, stamp, k, 0.0)
        assert not pushed.restarted and pushed.jump is None
        released += pushed.released
    assert path.drops == Counter(stamp_outlier=1)
    assert [i.payload for i in released] == [k for k in range(40) if k != 20]


def test_a_confirmed_jump_back_restarts_and_keeps_its_inputs():
    path = InputPath((ODOMETRY, OBSERVATIONS), silence=0.0, jump_threshold=1.0, confirmations=3)
    for k in range(10):
        path.push(ODOMETRY, 1000.0 + 0.1 * k, k, 0.0)
    results = [path.push(kind, stamp, None if kind == ODOMETRY else EMPTY, 0.0)
               for kind, stamp in ((ODOMETRY, 10.0), (OBSERVATIONS, 10.05), (ODOMETRY, 10.1))]
    assert [r.restarted for r in results] == [False, False, True]
    assert results[-1].jump.backward and results[-1].jump.size == pytest.approx(990.9)
    assert [i.stamp for i in results[-1].released] == [10.0, 10.05, 10.1]
    assert not path.drops
    # Without restart (reset_on_time_jump false) the old time line stays: the jump is out of order.
    path = InputPath((ODOMETRY,), silence=0.0, jump_threshold=1.0, restart_on_jump_back=False)
    path.push(ODOMETRY, 1000.0, 0, 0.0)
    for k in range(3):
        pushed = path.push(ODOMETRY, 10.0 + k, 0, 0.0)
    assert not pushed.restarted and pushed.released == [] and path.drops["out_of_order"] == 3


def test_a_far_future_stamp_does_not_block_later_inputs():
    """issue 12 defect 6: one far-future observation, a pause, then inputs continue: none is lost."""
    path = InputPath((ODOMETRY, OBSERVATIONS), silence=1.0, jump_threshold=1.0)
    used = []
    wall = 0.0
    for k in range(100):
        t, wall = 0.025 * k, 0.025 * k + (1.2 if k >= 50 else 0.0)       # a 1.2 s pause after k = 50
        used += path.push(ODOMETRY, t, None, wall).released
        if k % 8 == 0:
            used += path.push(OBSERVATIONS, t if k != 40 else t + 1e6, obs(5.0), wall).released
        used += path.release(wall)
    used += path.flush()
    assert path.drops == Counter(stamp_outlier=1)
    assert sum(i.kind == ODOMETRY for i in used) == 100 and sum(i.kind == OBSERVATIONS for i in used) == 12


def test_gap_detector_counts_lost_motion_messages():
    gaps = GapDetector((ODOMETRY,))
    stamps = [0.025 * k for k in range(100) if k not in (40, 41, 42, 70)]
    lost = [gaps.observe(ODOMETRY, t) for t in stamps]
    assert sum(lost) == 4 and gaps.drops == Counter(odometry_lost=4)
    # Sustained loss of every other message does not stretch the learnt period.
    lost = [gaps.observe(ODOMETRY, 0.025 * k) for k in range(100, 300, 2)]
    assert sum(lost) == 99
    # A stream that is not regular (a detector publishing only what it sees) is never judged.
    gaps = GapDetector((OBSERVATIONS,))
    rng = np.random.default_rng(0)
    assert sum(gaps.observe(OBSERVATIONS, t) for t in np.cumsum(rng.exponential(0.2, 200))) == 0


def test_a_message_that_comes_after_its_successors_was_not_lost():
    """Reliability, second round, item 3: reordered arrivals (an executor under load) open a gap
    that the late message then fills: nothing is counted lost; a message that never comes is."""
    gaps = GapDetector((ODOMETRY,))
    stamps = [0.025 * k for k in range(40)]
    for k in range(40, 100, 3):                        # every third pair arrives swapped
        stamps += [0.025 * (k + 1), 0.025 * k, 0.025 * (k + 2)]
    for t in stamps:
        gaps.observe(ODOMETRY, t)
    assert gaps.drops["odometry_lost"] == 0, gaps.drops
    for t in (0.025 * 100, 0.025 * 101, 0.025 * 102, 0.025 * 104):     # 103 never comes
        gaps.observe(ODOMETRY, t)
    assert gaps.drops["odometry_lost"] == 1


def test_lost_odometry_loses_no_motion():
    """Odometry is a pose: the increment over a gap carries the motion of the lost messages."""
    quiet = dict(odometry_translation_std=0.0, odometry_rotation_std=0.0, odometry_translation_per_meter=0.0,
                 odometry_rotation_per_radian=0.0, odometry_rotation_per_meter=0.0, position_jitter=1e-9,
                 heading_jitter=1e-9)        # noise-free, so the means compare exactly
    config = SlamConfig.from_dict({"motion": {"model": "odometry", **quiet},
                                   "filter": {"seed": 1, "num_particles": 20, "initial_pose_std": [0.0, 0.0, 0.0]}})
    poses = [(0.1 * k, 0.002 * k * k, 0.01 * k) for k in range(200)]

    def final(skip):
        slam = OnlineEMSlam(config)
        for k, pose in enumerate(poses):
            if k not in skip:
                slam.add_odometry(0.025 * k, pose)
        return slam.pose().mean
    full, lossy = final(set()), final({k for k in range(199) if k % 7 == 3 or 100 <= k < 140})
    assert np.allclose(full, poses[-1], atol=1e-6) and np.allclose(lossy, full, atol=1e-6), (full, lossy)


def test_feeder_skips_empty_clouds_and_observations_before_motion():
    config = SlamConfig.from_dict({"motion": {"model": "odometry"}, "filter": {"seed": 1, "num_particles": 10}})
    slam = OnlineEMSlam(config)
    feeder = Feeder(slam, "odom")
    assert feeder.apply(Input(0.0, OBSERVATIONS, payload=obs(5.0))).trajectory_point is None
    assert feeder.apply(Input(0.1, ODOMETRY, payload=(0.0, 0.0, 0.0))).moved
    fed = feeder.apply(Input(0.2, OBSERVATIONS, payload=EMPTY))
    assert fed.report is None and fed.trajectory_point[0] == 0.1
    assert feeder.apply(Input(0.3, ODOMETRY, payload=(0.1, 0.0, 0.0))).moved
    fed = feeder.apply(Input(0.3, OBSERVATIONS, payload=obs(5.0)), use_observations=False)
    assert fed.report is None and fed.trajectory_point[0] == pytest.approx(0.3)
    fed = feeder.apply(Input(0.4, OBSERVATIONS, payload=obs(5.0)))
    assert fed.report is not None and fed.trajectory_point[0] == pytest.approx(0.4)
    assert feeder.drops == Counter(no_motion_input=1, empty_cloud=1, overload=1)


def test_the_tie_rule_is_the_table_not_the_kind_values(monkeypatch):
    assert TIE_ORDER == (ODOMETRY, OBSERVATIONS, CONTROL)
    items = [Input(1.0, CONTROL, 1), Input(1.0, OBSERVATIONS, 2), Input(1.0, ODOMETRY, 3), Input(0.5, CONTROL, 4)]
    assert [i.seq for i in sorted(items)] == [4, 3, 2, 1]
    # Another table orders the same inputs otherwise: the kinds' values play no part.
    monkeypatch.setattr(inputs, "TIE_RANK", {CONTROL: 0, ODOMETRY: 1, OBSERVATIONS: 2})
    assert [i.seq for i in sorted(items)] == [4, 1, 3, 2]


def test_pipeline_feeds_released_inputs_and_calls_back_per_input_and_per_batch():
    config = SlamConfig.from_dict({"motion": {"model": "odometry"}, "filter": {"seed": 1, "num_particles": 10}})
    applied, settled = [], []
    pipeline = InputPipeline(OnlineEMSlam(config), "odom", input_delay=0.0, jump_threshold=1.0,
                             on_applied=lambda item, fed: applied.append((item.kind, item.stamp, fed)),
                             on_settled=lambda used, observed: settled.append((used, observed)))
    pipeline.push(ODOMETRY, 0.1, (0.0, 0.0, 0.0), 0.0)
    pipeline.push(OBSERVATIONS, 0.1, obs(5.0), 0.0)
    assert [(kind, stamp) for kind, stamp, _ in applied] == [(ODOMETRY, 0.1), (OBSERVATIONS, 0.1)]
    assert applied[0][2].moved and applied[1][2].report is not None
    assert settled == [(True, False), (True, True)]
    assert pipeline.estimator.last_stamp == pytest.approx(0.1)


def test_pipeline_sheds_observations_only_when_shedding_and_loaded():
    config = SlamConfig.from_dict({"motion": {"model": "odometry"}, "filter": {"seed": 1, "num_particles": 10}})
    for shedding, expected in ((False, 0), (True, 1)):
        pipeline = InputPipeline(OnlineEMSlam(config), "odom", 0.0, 1.0, shedding=shedding, clock=lambda: 1.0)
        pipeline.push(ODOMETRY, 0.1, (0.0, 0.0, 0.0), 0.0)
        pipeline.busy(1.0, 0.95)                       # above the limit (0.9 of the 1 s window)
        pipeline.push(OBSERVATIONS, 0.2, obs(5.0), 0.0)
        assert pipeline.drops["overload"] == expected and pipeline.max_load == pytest.approx(0.95)
        assert pipeline.feeder.motion_seen


def test_pipeline_sheds_observations_unread_while_the_motion_inputs_wait_too_long():
    """Reliability, second round, item 2: shedding by the time the inputs waited in their queues
    (input_max_wait), the motion input's wait or the cloud's own; never with shedding off."""
    config = SlamConfig.from_dict({"motion": {"model": "odometry"}, "filter": {"seed": 1, "num_particles": 10}})
    for shedding, max_wait, expected in ((True, 0.25, [False, True, True, False]),
                                         (True, 0.0, [False] * 4), (False, 0.25, [False] * 4)):
        pipeline = InputPipeline(OnlineEMSlam(config), "odom", 0.0, 1.0, shedding=shedding, max_wait=max_wait)
        verdicts = [pipeline.overdue(0.1)]
        pipeline.waited(0.3)                           # the last odometry waited 0.3 s
        verdicts.append(pipeline.overdue(0.1))
        pipeline.waited(0.01)
        verdicts += [pipeline.overdue(0.5), pipeline.overdue(0.2)]
        assert verdicts == expected, (shedding, max_wait)


def test_observations_shed_unread_keep_their_stream_on_the_time_line():
    """Car Park at 20x with 1,000 particles: every cloud shed for a while, the next one read was
    more than time_jump_threshold ahead of the lagging controls and of the last cloud the guard had
    seen, so it was held as a jump (4,439 stamp_outlier). A shed cloud's stamp now counts as heard."""
    config = SlamConfig.from_dict({"motion": {"model": "odometry"}, "filter": {"seed": 1, "num_particles": 10}})
    pipeline = InputPipeline(OnlineEMSlam(config), "odom", 1.0, 1.0, shedding=True, max_wait=0.25)
    pipeline.push(ODOMETRY, 0.0, (0.0, 0.0, 0.0), 0.0)
    pipeline.push(OBSERVATIONS, 0.0, obs(5.0), 0.0)
    for k in range(1, 40):                             # clouds shed up to 9.75 s, odometry at 5 s
        pipeline.shed(OBSERVATIONS, 0.25 * k, 0.0)
        if k <= 20:
            pipeline.push(ODOMETRY, 0.25 * k, (0.01 * k, 0.0, 0.0), 0.0)
    pipeline.push(OBSERVATIONS, 10.0, obs(5.0), 0.0)
    assert pipeline.path.guard.holding == 0 and "stamp_outlier" not in pipeline.drops
    assert pipeline.drops["overload"] == 39


def test_load_monitor():
    load = LoadMonitor(window=1.0, limit=0.9)
    for k in range(100):
        load.add(0.01 * k, 0.005)
    assert load.load(1.0) == pytest.approx(0.5, abs=0.02) and not load.overloaded(1.0)
    for k in range(100, 200):
        load.add(0.01 * k, 0.0095)
    assert load.overloaded(2.0)
    assert load.load(5.0) == 0.0


def test_stamp_guard_refutes_only_by_the_stream_that_jumped():
    guard = StampGuard(1.0, confirmations=3)
    guard.check(Input(100.0, ODOMETRY))
    guard.check(Input(100.0, OBSERVATIONS))
    assert guard.check(Input(5.0, ODOMETRY)).action == "hold"
    assert guard.check(Input(100.1, OBSERVATIONS)).action == "accept"   # a lagging stream: no refutation
    assert guard.holding == 1
    assert guard.check(Input(100.1, ODOMETRY)).action == "accept"       # the jumped stream is back
    assert guard.holding == 0 and guard.drops == Counter(stamp_outlier=1)


def test_a_watched_stream_before_any_merged_input_is_judged_on_its_own_line():
    """Found by a whole-suite CI run: in control mode the node crashed (ValueError: max() of an
    empty sequence) when two odometry messages came before the first control or cloud."""
    path = InputPath((CONTROL, OBSERVATIONS), silence=1.0, jump_threshold=1.0)
    assert path.on_time_line(ODOMETRY, 5.0)
    path.watch(ODOMETRY, 5.0)
    assert path.on_time_line(ODOMETRY, 5.05)
    assert not path.on_time_line(ODOMETRY, 100.0)         # far from its own line
    path.watch(ODOMETRY, 5.05)
    for k in range(3):                                    # a jump against the watched line only
        path.push(CONTROL, 50.0 + 0.025 * k, (1.0, 0.0), 0.0)
    path.push(CONTROL, 50.1, (1.0, 0.0), 0.0)


def test_a_watched_stream_running_behind_under_load_stays_on_the_time_line():
    """Re-measuring the sustained rate (issue 12): with control driving the motion, odometry that
    fell more than time_jump_threshold behind the controls under load was refused as stamp_outlier
    (3125 of 5001 at 8x) and counted as lost as well."""
    path = InputPath((CONTROL, OBSERVATIONS), silence=1.0, jump_threshold=1.0)
    on_line = []

    def odometry(stamp):
        on_line.append(path.on_time_line(ODOMETRY, stamp))
        if on_line[-1]:
            path.watch(ODOMETRY, stamp)
    for k in range(10):                                   # together at first
        path.push(CONTROL, 0.025 * k, (1.0, 0.0), 0.0)
        odometry(0.025 * k)
    for k in range(10, 400):                              # then the controls run 10 s ahead
        path.push(CONTROL, 0.025 * k, (1.0, 0.0), 0.0)
    for k in range(10, 200):                              # odometry up to 5 s, 5-10 s behind
        odometry(0.025 * k)
    assert all(on_line), on_line.index(False)
    assert path.drops == Counter()
    # A lone bad stamp of the watched stream is still off the time line.
    assert not path.on_time_line(ODOMETRY, 0.0 - 5.0) and not path.on_time_line(ODOMETRY, 1e6)


def test_a_watched_stream_running_ahead_under_load_stays_on_the_time_line():
    """Reliability, second round, item 2 (Car Park at 20x): the node reads each queue in batches, so
    the odometry, cheap to read, ran more than time_jump_threshold ahead of the controls, whose
    updates are slow, and 5,044 odometry messages were refused as stamp_outlier and their holes
    counted as odometry_lost."""
    path = InputPath((CONTROL, OBSERVATIONS), silence=1.0, jump_threshold=1.0)
    on_line = []
    for k in range(400):                                  # odometry 0-10 s
        on_line.append(path.on_time_line(ODOMETRY, 0.025 * k))
        path.watch(ODOMETRY, 0.025 * k)
        if k < 200:                                       # the controls 5 s behind at the end
            path.push(CONTROL, 0.025 * k, (1.0, 0.0), 0.0)
    assert all(on_line), on_line.index(False)
    assert path.drops == Counter()
    assert not path.on_time_line(ODOMETRY, 1e6) and not path.on_time_line(ODOMETRY, 2.0)


def test_a_watched_stream_keeps_its_line_when_sparse_clouds_jump_ahead_of_lagging_controls():
    """Issue 25's fleet replay at 5x: a robot's clouds (one every few seconds) overtook its lagging
    control queue by more than time_jump_threshold; three of them confirmed a jump ahead, the guard
    forgot the odometry's own line, and every later odometry message, behind the clouds, was
    refused as stamp_outlier (28,000 of 30,000 per robot)."""
    path = InputPath((CONTROL, OBSERVATIONS), silence=1.0, jump_threshold=1.0)
    for k in range(40):                                   # 0-1 s: together
        path.push(CONTROL, 0.025 * k, (1.0, 0.0), 0.0)
        path.watch(ODOMETRY, 0.025 * k)
    for t in (3.0, 3.1, 3.2):                             # clouds 2 s ahead of the queues: a jump ahead
        path.push(OBSERVATIONS, t, EMPTY, 0.0)
    assert path.guard.holding == 0
    on_line = []
    for k in range(40, 120):                              # the queues catch up, 1-3 s
        path.push(CONTROL, 0.025 * k, (1.0, 0.0), 0.0)
        on_line.append(path.on_time_line(ODOMETRY, 0.025 * k))
        if on_line[-1]:
            path.watch(ODOMETRY, 0.025 * k)
    assert all(on_line), on_line.index(False)
    assert "stamp_outlier" not in path.drops


def test_a_stream_draining_late_across_a_loop_seam_restarts_once_not_at_every_input():
    """Soak (issue 12 figures): the Car Park bag played in a loop into a loaded node; the controls'
    queue drained 3.5 s behind the clouds across the seam. After the clouds confirmed the jump back,
    every later batch of three inputs of either stream looked like another jump against the other
    stream's stamps: 31 restarts in 3 s, each putting the robot back at the initial pose (with the
    map kept, 15 landmarks became 29). A confirmed jump now moves only the streams that made it."""
    path = InputPath((CONTROL, OBSERVATIONS), silence=1.0, jump_threshold=1.0)
    lag, period = 3.5, 125.0

    def stamp(w):                                        # bag time of play time w, looped
        return 100.0 + (w % period)
    restarts = []
    for k in range(int(2.5 * period / 0.025)):
        w = 0.025 * k
        arrivals = [(CONTROL, stamp(w - lag), (1.0, 0.0))] if w >= lag else []
        arrivals += [(OBSERVATIONS, stamp(w), EMPTY)] if k % 8 == 0 else []
        for kind, t, payload in arrivals:
            if path.push(kind, t, payload, w).restarted:
                restarts.append(round(w, 2))
    # The controls starting 3.5 s behind the clouds lag, and are no jump (they restarted the pose
    # once, 3.5 s into the run, before); per seam the clouds and, 3.5 s later, the controls each
    # move to the new pass once.
    assert restarts == [125.4, 128.55, 250.4, 253.55], restarts
    assert "stamp_outlier" not in path.drops


def test_a_watched_stream_follows_a_jump_confirmed_by_the_merged_streams():
    path = InputPath((CONTROL, OBSERVATIONS), silence=0.0, jump_threshold=1.0)
    for k in range(20):
        path.push(CONTROL, 100.0 + 0.025 * k, (1.0, 0.0), 0.0)
        assert path.on_time_line(ODOMETRY, 100.0 + 0.025 * k)
        path.watch(ODOMETRY, 100.0 + 0.025 * k)
    restarted = [path.push(CONTROL, 10.0 + 0.025 * k, (1.0, 0.0), 0.0).restarted for k in range(3)]
    assert restarted == [False, False, True]
    assert path.on_time_line(ODOMETRY, 10.05)          # odometry of the new line: used again


def test_a_forward_time_jump_is_a_gap_not_lost_messages():
    """Reliability, second round, item 3: stamps jump 1e4 s ahead (confirmed by three inputs):
    nothing was lost, so no odometry_lost / observations_lost; the loss detection still works after."""
    path = InputPath((ODOMETRY, OBSERVATIONS), silence=1.0, jump_threshold=1.0)
    for k in range(200):
        t = 0.05 * k + (1e4 if k >= 100 else 0.0)
        path.push(ODOMETRY, t, None, 0.05 * k)
        if k % 4 == 0:
            path.push(OBSERVATIONS, t, obs(5.0), 0.05 * k)
    assert path.drops["odometry_lost"] == 0 and path.drops["observations_lost"] == 0, path.drops
    path.push(ODOMETRY, 0.05 * 205 + 1e4, None, 10.3)          # 5 odometry messages missing after the jump
    assert path.drops["odometry_lost"] == 5


def test_a_streams_first_inputs_behind_the_others_lag_and_are_no_jump():
    """Five node processes fed at once (test_fleet_distributed_live.py): a robot's controls all
    reached its node before its first cloud, stamped seconds earlier; three such clouds were
    taken for a jump back and restarted the robot's pose and time line.  A stream's first inputs
    are judged behind only against its own line: they lag."""
    path = InputPath((CONTROL, OBSERVATIONS), silence=1.0, jump_threshold=1.0)
    pushed = [path.push(CONTROL, 1000.0 + 0.2 * k, (1.0, 0.0), 0.0) for k in range(20)]
    pushed += [path.push(OBSERVATIONS, 1000.1 + 0.2 * k, EMPTY, 0.0) for k in range(20)]
    assert not any(p.restarted or p.jump is not None for p in pushed)
    assert "stamp_outlier" not in path.drops


def test_clouds_are_judged_for_loss_once_an_empty_one_came():
    """MRCLAM's camera publishes a cloud per frame with a barcode read: regular at first (frames
    0.22-0.24 s apart), then frames left out, which were counted as 300-1800 lost clouds per robot
    in 600 s.  A detector shows that it reports every scan by an empty cloud; only then are its
    gaps losses."""
    def run(first_empty: bool) -> Counter:
        path = InputPath((CONTROL, OBSERVATIONS), silence=0.0, jump_threshold=1.0)
        scans = [0.23 * k for k in range(40)] + [0.23 * k for k in range(43, 80)]     # 3 frames without a cloud
        for k, t in enumerate(scans):
            path.push(CONTROL, 1000.0 + t - 0.01, (1.0, 0.0), 0.0)
            path.push(OBSERVATIONS, 1000.0 + t, EMPTY if (first_empty and k == 3) else obs(5.0), 0.0)
        return path.drops
    assert run(first_empty=False)["observations_lost"] == 0
    assert run(first_empty=True)["observations_lost"] == 3
