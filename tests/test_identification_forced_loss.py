"""Issue 43, item 9: the live path that flags lost samples, exercised with a real loss.

The identification node takes its samples from a shallow DDS history (200 samples here instead of 10,000) and the
test stops spinning it for 1 s while the simulator publishes at 490 Hz (about 290 samples lost): DDS overwrites
what the node does not take, as under a load that stalls the node. Every window whose span covers the lost samples
must say so: counted in its event (``lost_samples`` > 0, all of them when the loss lies inside the window) and never
published as ``clean``; windows are 8 s every 1 s, so several covering windows are published, flagged
``lost_samples``. Measured in one run: 290 lost, 8 windows covering the loss (6 flagged, 2 refused: too little data
between gaps), 0 clean.
"""
from __future__ import annotations

import time

from tests.ros_helpers import NodeProcess, private_domain_id


def test_every_window_covering_a_forced_loss_is_flagged(monkeypatch):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from aeropend_core.model.parameters import SAMPLE_TIME
    from aeropend_ros import identification_node
    monkeypatch.setattr(identification_node, 'QUEUE_DEPTH', 200)       # 0.4 s of samples: a stall loses the rest
    domain_id = private_domain_id()
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = identification_node.IdentificationNode(
        context=context, parameter_overrides=[Parameter('window_s', value=8.0), Parameter('hop_s', value=1.0)])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)

    def spin(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)

    try:
        with NodeProcess('aeropend_ros.sim_node', ['-p', 'psnr_db:=40.0'], domain_id), \
                NodeProcess('aeropend_ros.excitation_node', [], domain_id):
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and node.samples_received < int(8.0 / SAMPLE_TIME):
                spin(0.1)
            assert node.samples_received >= int(8.0 / SAMPLE_TIME), 'the simulator\'s samples did not arrive'
            with node.lock:
                last_before, stamp_before = node.sequence[-1], node.stamps[-1]
            missed_before = node.samples_missed
            time.sleep(1.0)                              # the stall: nothing is taken, DDS overwrites the history
            spin(0.2)
            with node.lock:
                after = [(s, t) for s, t in zip(node.sequence, node.stamps) if s > last_before]
            assert after, 'no sample after the stall'
            lost = node.samples_missed - missed_before
            stall_gap = after[0][0] - last_before - 1             # the samples the stall itself lost
            assert stall_gap >= 150, f'the stall lost only {stall_gap} samples'
            loss = ((stamp_before - node.first_stamp_ns) * 1e-9, (after[0][1] - node.first_stamp_ns) * 1e-9)
            spin(14.0)                                   # windows past the loss come due and are computed
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline and node.pending is not None and not node.pending.done():
                spin(0.2)
            spin(0.5)
            missed_in_all = node.samples_missed - missed_before   # the stall's, and any lost while catching up
        covering = [e for e in node.window_events if e.start_s < loss[1] and e.stop_s > loss[0]]
        computed = [e for e in covering if e.state != "skipped"]
        assert computed, [(e.start_s, e.stop_s, e.state) for e in node.window_events]
        for event in computed:
            assert event.lost_samples > 0 and event.state != 'clean', (loss, event)
            if event.state == 'flagged':
                assert 'lost_samples' in event.data and 'lost' in event.message, event
            if event.start_s < loss[0] and event.stop_s > loss[1]:       # the whole loss inside: every sample counted
                # (the node can lose more samples while it catches up after the stall, even on an idle machine: a
                # second gap of 47 samples inside the same window was seen; so the count lies between the stall's
                # own gap and every sample missed from the stall to the end)
                assert stall_gap <= event.lost_samples <= missed_in_all, (stall_gap, lost, missed_in_all, event)
        assert any(e.state == 'flagged' for e in computed), [(e.start_s, e.state) for e in covering]
        # a window entirely after the loss is not blamed for it
        later = [e for e in node.window_events if e.start_s > loss[1] + 0.1 and e.state not in ('skipped',)]
        assert all(e.lost_samples < lost for e in later), [(e.start_s, e.lost_samples) for e in later]
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
