"""What the load test (bench/load_test.py) relies on, checked without timing: the identification node's sample
counters and its bounded history, and the load test's own sequence accounting."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.ros_helpers import private_domain_id

ROOT = Path(__file__).resolve().parents[1]


def _sample_bytes(sequence: int, stamp_ns: int) -> bytes:
    from rclpy.serialization import serialize_message

    from aeropend_ros import topics
    sample = topics.Sample(stamp_ns, 0.1, 1.0, 0.2, 0.3, sequence)
    return serialize_message(topics.sample_to_msg(sample))


def test_identification_counts_received_and_missed_samples_and_keeps_one_window():
    """Samples fed straight into the node's callback (the exact CDR bytes a subscription hands it): 12 samples
    skipped in two gaps are counted as missed, and 60 s of samples leave at most one window + one hop buffered."""
    domain_id = private_domain_id()         # the node's diagnostics stay off other tests' domains
    import rclpy
    from rclpy.parameter import Parameter

    from aeropend_core.model.parameters import SAMPLE_TIME
    from aeropend_ros.identification_node import IdentificationNode
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    window_s, hop_s = 4.0, 0.5
    node = IdentificationNode(context=context, parameter_overrides=[Parameter('window_s', value=window_s),
                                                                    Parameter('hop_s', value=hop_s)])
    try:
        total = int(60.0 / SAMPLE_TIME)
        skipped = set(range(100, 110)) | {500, 501}
        start_ns = 1_000_000_000_000
        fed = 0
        longest = 0
        for sequence in range(total):
            if sequence in skipped:
                continue
            node._on_sample(_sample_bytes(sequence, start_ns + round(sequence * SAMPLE_TIME * 1e9)))
            fed += 1
            longest = max(longest, len(node.stamps))
        assert node.samples_received == fed == total - len(skipped)
        assert node.samples_missed == len(skipped)
        # History: trimmed to the last window at each hop, so never more than window + hop (+ the sample kept
        # before the window start), and the last window is complete.
        assert longest <= (window_s + hop_s) / SAMPLE_TIME + 2, longest
        assert len(node.stamps) >= window_s / SAMPLE_TIME
        assert len(node.sequence) == len(node.stamps) == len(node.signals['angle'])
        assert node.sequence[-1] == total - 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_load_test_sequence_accounting():
    """Gaps, duplicates and order as the load test counts them against the published samples 0..n-1."""
    from aeropend_core.signals.sequence import sequence_report
    clean = sequence_report(np.arange(10), 10)
    assert (clean['missing'], clean['gaps'], clean['duplicates'], clean['out_of_order']) == (0, 0, 0, 0)
    report = sequence_report(np.array([1, 2, 2, 4, 3, 6, 7]), 10)
    assert report['recorded'] == 7 and report['unique'] == 6 and report['duplicates'] == 1
    assert report['missing'] == 4                      # 0, 5, 8, 9
    assert report['gaps'] == 3                         # before 1, between 4 and 6, after 7
    assert report['out_of_order'] == 1                 # 4 -> 3
