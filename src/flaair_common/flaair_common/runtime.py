"""Run a FLAAIR node: parameter errors become one
clear line, Ctrl-C and SIGTERM shut down cleanly.
"""

from __future__ import annotations

import faulthandler
import math
import os
import select
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable

# A node takes a second or more to import (rclpy, numba) and build (JIT compilation): a Ctrl-C or
# SIGTERM in that time is remembered here, before the slow imports below, and makes run_node
# return at once, instead of a KeyboardInterrupt traceback from the middle of an import.
# Before this module is imported (Python starting, the node module's first imports) nothing of
# ours runs: the launchers (`bin/flaair run`, flaair_common.graph.Graph) start a node with
# SIGINT and SIGTERM blocked, so one sent then stays pending, and it is unblocked here, right
# after the handlers are in place: the pending signal is remembered like any other early one.
_DEFERRED_SIGNALS = {signal.SIGINT, signal.SIGTERM}
_early_signals: list[int] = []


def _remember_early_signal(signum: int, _frame: object) -> None:
    _early_signals.append(signum)


def _is_node_process() -> bool:
    """True in a node's own process: started as
    <prefix>/lib/<package>/<executable> (ros2 run, bin/flaair run).
    """
    path = os.path.abspath(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    return os.path.basename(os.path.dirname(os.path.dirname(path))) == "lib"


if _is_node_process() and threading.current_thread() is threading.main_thread():
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _remember_early_signal)
    if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _remember_early_signal)
    _blocked = _DEFERRED_SIGNALS & signal.pthread_sigmask(signal.SIG_BLOCK, [])
    if _blocked:  # started by a launcher that deferred them: a pending one is delivered now
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _blocked)
    # `kill -USR1 PID` writes every thread's stack to the node's log (where is it stuck?)
    faulthandler.register(signal.SIGUSR1, all_threads=True)

import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.impl.logging_severity import LoggingSeverity
from rclpy.node import Node

from flaair_common import intra
from flaair_model.config import node_parameters
from flaair_model.notes import ERROR as ERROR_LEVEL
from flaair_model.notes import Note
from flaair_model.schema import ParameterError, ParamSpec

# at exit, a node's reliable readers get this long (in all) to acknowledge its last messages: a
# recorder half a second of signal behind on an overloaded machine needed more than the 2 s this
# was (the tail of a soak run's drive was lost). It returns at once when every reader has acked;
# a reader killed -9 is waited for in full (until DDS drops it), hence not more.
ACK_WAIT_S = 5.0
# DDS copies a reader thread has not sent in its gaps for this long: the main thread sends them
DEFERRED_BACKSTOP_S = 0.05
# A node told to stop has ended within this, whatever hangs on the way (closing, the acks, DDS's
# teardown): then the stacks of its threads go to its log and it exits 1 (faulthandler). A
# launcher that waits for its node kills it sooner (graph.STOP_TIMEOUT_S, 15 s); this bounds a
# node nobody waits for, as after a kill -9 of its launcher (a CI run once found a node still
# running 30 s after it, cause unknown). Above ACK_WAIT_S and a recorder's close under load.
EXIT_DEADLINE_S = 30.0
# ... and SIGALRM (its default action ends the process) this much later, should even
# faulthandler be gone (a hang after the interpreter's finalisation, in a library's destructor)
EXIT_ALARM_MARGIN_S = 5


def help_text(doc: str, specs: list[ParamSpec], config_file: str, node_name: str) -> str:
    """The node's --help: its docstring and a table of parameters with defaults and ranges."""
    try:
        defaults = node_parameters(config_file, node_name)
    except ValueError:
        defaults = {}
    lines = [
        doc.strip(),
        "",
        f"Parameters (defaults from config/{config_file}; set with --ros-args -p NAME:=VALUE):",
    ]
    for spec in specs:
        allowed = ""
        if spec.choices:
            allowed = " {" + "|".join(spec.choices) + "}"
        elif spec.min_value is not None or spec.max_value is not None:
            allowed = f" [{spec.min_value}, {spec.max_value}]"
        lines.append(
            f"  {spec.name} ({spec.type.__name__}, default {defaults.get(spec.name)!r}){allowed}"
        )
        lines.append(f"      {spec.description}")
    return "\n".join(lines)


def make_executor(default: str = "events"):
    """Rclpy's C++ EventsExecutor by default, or the SingleThreadedExecutor.

    The EventsExecutor takes a third of the CPU per message (bench/bench_closed_loop.py:
    ping-pong ~200 us vs ~600 us on the 2-core machine), which bounds a graph moving 2000
    blocks/s per stream. FLAAIR_EXECUTOR=single|events overrides `default` for every node
    (for comparisons, or should the experimental executor misbehave on another install).
    """
    kind = os.environ.get("FLAAIR_EXECUTOR", default)
    if kind not in ("single", "events"):
        raise ValueError(f"FLAAIR_EXECUTOR must be 'single' or 'events', got {kind!r}")
    if kind == "events":
        return EventsExecutor()
    return SingleThreadedExecutor()


def run_node(
    make_node: Callable[[], Node],
    specs: list[ParamSpec],
    config_file: str,
    node_name: str,
    args: list[str] | None = None,
    executor_kind: str = "events",
) -> int:
    """Initialise rclpy, build the node, spin until shutdown; return a process exit code.

    executor_kind is the default of `make_executor` (the recorder drains its queues inside
    a callback, which only the SingleThreadedExecutor allows).

    A refused parameter (or any other ValueError while the node is built: a bad value in a
    file it reads) prints `<node>: <reason>` and returns 2. SIGINT and SIGTERM stop spinning,
    call the node's `close()` if it has one (flush files, zero the drive), then destroy the
    node and shut rclpy down; one that arrived while the node was still importing or being
    built ends it as soon as it is built (exit 0, no traceback).
    """
    args = sys.argv if args is None else args
    if any(a in ("-h", "--help") for a in args[1:]) and "--ros-args" not in args:
        print(
            help_text(
                sys.modules[make_node.__module__].__doc__ or "", specs, config_file, node_name
            )
        )
        return 0
    return run_nodes([make_node], args, executor_kind)


def default_exit_deadline_s() -> float | None:
    """EXIT_DEADLINE_S in a node's own process; None in any other (a test, a CLI that composes
    nodes in its own process: their own time limits rule there).
    """
    return EXIT_DEADLINE_S if _is_node_process() else None


def _arm_exit_deadline(deadline_s: float | None) -> None:
    """From now on the process ends within `deadline_s`, its threads' stacks on stderr if it hangs.

    Only the first call counts (a second Ctrl-C does not move the deadline); any thread may call.
    """
    with _exit_deadline_lock:
        if deadline_s is None or _exit_deadline_armed.is_set():
            return
        _exit_deadline_armed.set()
    faulthandler.dump_traceback_later(deadline_s, exit=True)
    signal.alarm(math.ceil(deadline_s) + EXIT_ALARM_MARGIN_S)


_exit_deadline_lock = threading.Lock()
_exit_deadline_armed = threading.Event()


def _watch_for_stop_signals(deadline_s: float | None) -> None:
    """Arm the exit deadline from a thread of its own as soon as SIGINT or SIGTERM arrives.

    Python runs a signal's handler only when the main thread comes back to the interpreter; a
    main thread stuck for good in a library's C code (a DDS lock) would never arm it. The
    interpreter's own C-level handler writes the signal's number to the wakeup fd at once: this
    thread waits on it. Call from the main thread once the stop handlers are in place.
    """
    if deadline_s is None:
        return
    read_fd, write_fd = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
    signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)

    def watch() -> None:
        select.select([read_fd], [], [])
        _arm_exit_deadline(deadline_s)

    threading.Thread(target=watch, name="exit-deadline", daemon=True).start()


def _init_ros(args: list[str]) -> bool:
    """Initialise rclpy with `args`; False (said on stderr) for a malformed --ros-args word."""
    try:
        rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    except _rclpy_impl.RCLError as exc:  # a malformed --ros-args word (`-p name:=`, ...)
        why = str(exc).split(", at ")[0].removeprefix("failed to initialize rcl: ")
        print(f"{sys.argv[0].rsplit('/', 1)[-1]}: bad --ros-args: {why}", file=sys.stderr)
        return False
    return True


def _build_nodes(makers: list[Callable[[], Node]], program: str) -> list[Node] | None:
    """The nodes, built in order; None (said on stderr, those built closed, rclpy shut down) when
    one refuses a parameter or meets a bad value while building (ModelError, ...).
    """
    nodes: list[Node] = []
    try:
        for make_node in makers:
            nodes.append(make_node())
    except ValueError as exc:
        text = str(exc) if isinstance(exc, ParameterError) else f"{type(exc).__name__}: {exc}"
        print(f"{program}: {text}", file=sys.stderr)
        for node in reversed(nodes):
            _close(node)
        rclpy.try_shutdown()
        return None
    return nodes


def run_nodes(
    makers: list[Callable[[], Node]],
    args: list[str] | None = None,
    executor_kind: str = "events",
    bus: intra.Bus | None = None,
    exit_deadline_s: float | None = None,
) -> int:
    """Build several nodes in one process and spin them in one executor (a container).

    With a `bus`, block streams between them travel in-process (`flaair_common.intra`): the
    loop drains it between executor spins. Shutdown closes the nodes last built first (a
    controller's zero block reaches the actuator's node before that node closes).
    From a stop request on, the process ends within `exit_deadline_s` (None:
    `default_exit_deadline_s()`), see EXIT_DEADLINE_S.
    """
    args = sys.argv if args is None else args
    if exit_deadline_s is None:
        exit_deadline_s = default_exit_deadline_s()
    if _early_signals:
        return 0
    intra.install(bus)
    if not _init_ros(args):
        return 2
    executor = make_executor(executor_kind)
    stop_requested = bool(_early_signals)
    stop_signals: list[int] = []

    def _stop(signum: int, _frame: object) -> None:
        # Only set a flag: shutting the context down here would break a callback mid-publish.
        nonlocal stop_requested
        stop_requested = True
        stop_signals.append(signum)

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    _watch_for_stop_signals(exit_deadline_s)  # arms the deadline the moment either arrives
    program = sys.argv[0].rsplit("/", 1)[-1]
    nodes = _build_nodes(makers, program)
    if nodes is None:
        return 2
    for node in nodes:
        executor.add_node(node)
    # Background blocks and deferred DDS copies queued by another thread wait for this one: look
    # often if there can be any.
    idle_s = 0.002 if bus is not None and (bus.has_background() or bus.dds_batch > 1) else 0.05
    seen = -1
    try:
        while not stop_requested and rclpy.ok():
            # Where a reader thread delivers (a UDP bridge), blocks left queued are taken here only
            # when it has delivered nothing since the last look: it takes its own, at its own
            # priority, and a drain here would take the loop's blocks (and the interpreter lock)
            # from it. Elsewhere (lockstep) this thread's own callbacks leave them: drain at once.
            if (
                bus is not None
                and bus.pending()
                and (not bus.threaded or bus.delivered == seen)
                and bus.drain() > 0
            ):
                executor.spin_once(timeout_sec=0)
            else:
                seen = bus.delivered if bus is not None else -1
                # a reader thread sends the DDS copies in its gaps (intra.use_gap)
                if bus is not None:
                    bus.run_deferred(older_than_s=DEFERRED_BACKSTOP_S if bus.threaded else 0.0)
                executor.spin_once(
                    timeout_sec=0.002 if bus is not None and bus.pending() else idle_s
                )
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        _arm_exit_deadline(exit_deadline_s)
        if nodes:
            why = signal.Signals(stop_signals[0]).name if stop_signals else "shutdown"
            nodes[0].get_logger().info(
                f"stopping ({why}): closing, then up to {ACK_WAIT_S:g} s for readers' acks"
                + (f"; ends within {exit_deadline_s:g} s" if exit_deadline_s is not None else "")
            )
        for node in reversed(nodes):
            _close(node)
            if bus is not None:
                bus.flush()  # the closing zero block reaches its in-process consumers
        wait_for_acks(nodes)
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def wait_for_acks(nodes: list[Node], timeout_s: float = ACK_WAIT_S) -> None:
    """Every reliable reader has what the nodes published (their last blocks, the zero drive)
    before the process goes: a writer that exits first takes the undelivered messages with it.
    Topics still unacknowledged when `timeout_s` is up are named in the log.
    """
    deadline = time.monotonic() + timeout_s
    for node in nodes:
        late = []
        for publisher in node.publishers:
            left_s = max(0.0, deadline - time.monotonic())
            try:
                if not publisher.wait_for_all_acked(Duration(nanoseconds=int(left_s * 1e9))):
                    late.append(publisher.topic_name)
            except Exception:
                return
        if late:
            node.get_logger().warning(
                f"not acknowledged by every reader within {timeout_s:g} s, may be lost: "
                f"the last messages on {', '.join(late)}"
            )


def _close(node: Node) -> None:
    close = getattr(node, "close", None)
    if callable(close):
        close()


INFO, WARN, ERROR = LoggingSeverity.INFO, LoggingSeverity.WARN, LoggingSeverity.ERROR
SEVERITY = {"info": INFO, "warning": WARN, "error": ERROR}  # the pure cores' note levels


def log(logger, severity: LoggingSeverity, text: str, depth: int = 1) -> None:
    """What `logger.info/warning/error(text)` writes
    (console and /rosout), at a hundredth of the cost.

    rclpy finds each call's source line with `inspect.getframeinfo`, which searches every loaded
    module: 1.1 ms a warning here, on the thread that logs. A live loop's UDP reader that logged its
    first late blocks so fell further behind with each one. `depth` counts the frames up to the
    caller the record names.
    """
    if logger.is_enabled_for(severity):
        caller = sys._getframe(depth)
        _rclpy_impl.rclpy_logging_rcutils_log(
            severity,
            logger.name,
            text,
            caller.f_code.co_name,
            caller.f_code.co_filename,
            caller.f_lineno,
        )


_last_warned: dict[tuple, float] = {}


def warn_counted(
    logger, count: int, text: str, every_up_to: int = 10, key: object = None, depth: int = 1
) -> None:
    """Log a warning every time for the first `every_up_to` occurrences, then at most once a second.

    The throttle is kept here, per `key` (default: the calling line): rclpy's own throttle looks up
    its caller with `inspect` on every call, logged or not, which cost a fault-flooded bridge a
    fifth of its CPU. `depth` counts the frames up to the caller the record names.
    """
    if count > every_up_to:
        caller = sys._getframe(depth)
        key = (id(logger), caller.f_code, caller.f_lineno) if key is None else (id(logger), key)
        now = time.monotonic()
        if now - _last_warned.get(key, -math.inf) < 1.0:
            return
        _last_warned[key] = now
    log(logger, WARN, text, depth=depth + 1)


def log_notes(
    logger, notes: Iterable[Note], count_of: Callable[[str], int] = lambda _counter: 0
) -> None:
    """Log a core's notes, the same way in every node.

    Errors and uncounted notes are logged at their level; a counted warning (`Note.counter`) is
    logged every time for its first ten occurrences, then at most once a second per counter.
    `count_of(counter)` gives the count now (the core's state holds it).
    """
    for note in notes:
        if note.counter and note.level != ERROR_LEVEL:
            warn_counted(logger, count_of(note.counter), note.text, key=note.counter, depth=2)
        else:
            log(logger, SEVERITY[note.level], note.text, depth=2)
