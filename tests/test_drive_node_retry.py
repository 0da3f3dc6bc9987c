"""drive_node in lockstep with a plant that never answers: retries (warnings), then the run's end
(info), and the node keeps running. In process, on a fake clock (tests/composed.py): the timings
are exact.
"""

from __future__ import annotations

import numpy as np

from composed import composed


def test_lockstep_drive_retries_then_ends_on_a_zero_block_and_keeps_running(
    monkeypatch, tmp_path, capfd
) -> None:
    from flaair_sim.drive_node import DriveNode

    params = {
        "drive_node": {
            "pacing": "lockstep",
            "lockstep_window_blocks": 1,
            "ack_retry_s": 0.2,
            "run_time_s": 0.002,
            "frequency_hz": 140.0,
        }
    }  # 4 blocks of 10 samples
    with composed(monkeypatch, [DriveNode], params, tmp_path, local_topics=()) as loop:
        drive = loop.node("drive_node")
        sent: list[tuple[float, int, float]] = []  # (clock, first sample, peak |drive|)
        t0 = loop.clock.now_s
        monkeypatch.setattr(
            drive.publisher,
            "publish",
            lambda stamp_ns, fields: sent.append(
                (
                    round(loop.clock.now_s - t0, 6),
                    fields["first_sample_index"],
                    float(np.abs(fields["drive_v"]).max()),
                )
            ),
        )
        # a silent plant: it subscribes to the drive and
        # offers the sensor stream, and never publishes
        monkeypatch.setattr(drive.publisher, "subscription_count", lambda: 1)
        monkeypatch.setattr(drive.ack, "get_publisher_count", lambda: 1)
        loop.run_for(3.0)
        # still running after the warnings and the info line
        assert drive.context.ok()
    log = capfd.readouterr().err
    # one block per retry (nothing acknowledges): the first at the first
    # 2 ms tick, each retry at the first tick 0.2 s after the last send;
    # the zero block that ends the run right after the 4th; no more
    assert [index for _, index, _ in sent] == [0, 10, 20, 30, 40]
    assert all(peak > 0 for _, _, peak in sent[:4]) and sent[4][2] == 0.0
    assert [t for t, _, _ in sent] == [0.002, 0.204, 0.406, 0.608, 0.608]
    assert (
        log.count("no acknowledgement for 0.2 s") == 3
        and "run complete at sample 40; zero drive sent" in log
    )
