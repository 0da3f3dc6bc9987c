"""flaair_common.runtime.log: the console line and the /rosout record rclpy's logger writes, with
the caller's file, function and line, without rclpy's per-call source lookup (1.1 ms a call).
"""

from __future__ import annotations

import json
import sys
import textwrap

import pytest

from rosproc import isolated_env, run

SCRIPT = textwrap.dedent("""
    import json, sys, time
    import rclpy
    from rcl_interfaces.msg import Log
    from flaair_common.runtime import ERROR, INFO, WARN, log, log_notes, warn_counted
    from flaair_model.notes import Note

    rclpy.init()
    node = rclpy.create_node("fast_log_test")
    got = []
    node.create_subscription(Log, "/rosout", got.append, 100)
    logger = node.get_logger()
    time.sleep(0.5)

    def through_rclpy():
        logger.warning("from rclpy")

    def fast():
        log(logger, WARN, "from log")
        log(logger, INFO, "an info")
        log(logger, ERROR, "an error")
        for count in range(1, 5):
            warn_counted(logger, count, f"counted {count}", every_up_to=2)

    def noted():
        counts = iter(range(11, 15))   # past the first ten: once a second per counter
        notes = [Note("warning", f"gap {i}", "gaps") for i in range(4)]
        notes += [Note("error", "tripped", "gaps"), Note("info", "plain")]
        log_notes(logger, notes, lambda counter: next(counts))

    through_rclpy()
    fast()
    noted()
    deadline = time.monotonic() + 10
    while len(got) < 10 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    settle = time.monotonic() + 0.5   # anything more (a warning the throttle should have held back)
    while time.monotonic() < settle:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps([{"level": m.level, "name": m.name, "msg": m.msg, "file": m.file,
                       "function": m.function, "line": m.line}
                      for m in got if m.name == "fast_log_test"]))
    node.destroy_node()
    rclpy.shutdown()
""")


@pytest.mark.slow  # compares with rclpy's logger in a new process
def test_log_writes_what_rclpy_writes_and_names_the_caller(tmp_path) -> None:
    script = tmp_path / "fast_log.py"
    script.write_text(SCRIPT)
    env = isolated_env()
    env["RCUTILS_CONSOLE_OUTPUT_FORMAT"] = (
        "[{severity}] [{name}] {function_name}:{line_number}: {message}"
    )
    done = run([sys.executable, str(script)], env, timeout_s=60)
    assert done.returncode == 0, done.stderr
    records = json.loads(done.stdout.strip().splitlines()[-1])
    by_msg = {r["msg"]: r for r in records}
    rclpy_record, fast_record = by_msg["from rclpy"], by_msg["from log"]
    # rosout: same level and file as rclpy's own record; the line and function of the log() call
    assert fast_record["level"] == rclpy_record["level"] == 30
    assert fast_record["file"] == rclpy_record["file"] == str(script)
    assert (rclpy_record["function"], fast_record["function"]) == ("through_rclpy", "fast")
    lines = SCRIPT.splitlines()
    assert lines[fast_record["line"] - 1].strip() == 'log(logger, WARN, "from log")'
    assert (by_msg["an info"]["level"], by_msg["an error"]["level"]) == (20, 40)
    # warn_counted: the first two every time, then once a second; its record names its own caller
    assert [r["msg"] for r in records if r["msg"].startswith("counted")] == [
        "counted 1",
        "counted 2",
        "counted 3",
    ]
    assert by_msg["counted 1"]["function"] == "fast"
    # the console: the same format, the same fields
    console = [line for line in done.stderr.splitlines() if line.startswith("[")]
    assert "[WARN] [fast_log_test] through_rclpy:" in console[0] and console[0].endswith(
        ": from rclpy"
    )
    assert console[1] == f"[WARN] [fast_log_test] fast:{fast_record['line']}: from log"
    assert console[3].startswith("[ERROR] [fast_log_test] fast:")
    # log_notes: one counted warning per counter a second, errors and plain notes always; the
    # records name the caller of log_notes
    assert [r["msg"] for r in records if r["function"] == "noted"] == ["gap 0", "tripped", "plain"]
    assert [by_msg[m]["level"] for m in ("gap 0", "tripped", "plain")] == [30, 40, 20]
