"""Entry point of one node process: ``python -m tether.runner -`` with its RunSpec JSON on stdin.

The spec may carry this machine's CurveZMQ secret key, so the launcher never puts it on
the command line or in the environment (both readable by other users through /proc).
A node started by a launcher stops when the launcher dies, however it dies.

A node whose launch entry sets ``rt_priority`` runs under ``SCHED_FIFO`` at that priority
(:func:`apply_rt_priority`), as ros2_control's ``thread_priority`` does for its control loop: a
cyclic node (a CANopen SYNC producer, a drive simulator) then keeps its period on a loaded
machine, where normal scheduling lets other processes hold it off the CPU for tens of ms.
Where the process may not (no CAP_SYS_NICE, no ``rtprio`` limit), it says so in one line and
runs with normal scheduling.
"""
from __future__ import annotations

import ctypes
import importlib
import json
import faulthandler
import logging
import os
import signal
import sys
import threading
import time
from typing import Any, Callable

import msgspec

from tether.errors import ConfigError
from tether.node import Node
from tether.runtime import STOP_REPORT_TEXT, NodeRuntime, RunSpec

LOG_FORMAT = "%(levelname)s %(name)s: %(message)s"
PR_SET_PDEATHSIG = 1
ORPHAN_GRACE_S = 5.0
log = logging.getLogger("tether.runner")


def read_spec_arg(arg: str) -> Any:
    """The JSON spec: ``-`` reads it from stdin (the launcher's pipe); anything else is the JSON itself."""
    if arg == "-":
        text = sys.stdin.read()
        sys.stdin.close()
        return json.loads(text)
    return json.loads(arg)


def watch_parent(parent_pid: int, stop: Callable[[], None]) -> None:
    """Stop when ``parent_pid`` (the launcher) dies, and exit if stopping takes longer than a grace period.

    Linux delivers SIGTERM on the parent's death (``PR_SET_PDEATHSIG``; set here, so the
    parent's death between fork and this call is caught by the ``getppid`` check); a
    thread polling ``getppid`` covers other systems and a node whose SIGTERM handler hangs.
    """
    if parent_pid <= 0:
        return
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    except (OSError, AttributeError):
        pass                                    # not Linux: the polling thread alone

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(0.2)
        log.error("launcher (pid %d) is gone: stopping", parent_pid)
        stop()
        time.sleep(ORPHAN_GRACE_S)
        log.error("did not stop within %.0f s of the launcher's death: exiting", ORPHAN_GRACE_S)
        os._exit(3)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def load_node_class(path: str) -> type[Node]:
    """Import ``module:Class`` and check it is a Node; ``ConfigError`` saying what is wrong otherwise."""
    module_name, sep, class_name = path.partition(":")
    if not sep or not module_name or not class_name:
        raise ConfigError(f"node {path!r} must be 'module.path:ClassName'")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"cannot import module {module_name!r}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - a broken module is a config error for the user
        raise ConfigError(f"importing {module_name!r} failed: {type(exc).__name__}: {exc}") from None
    cls = getattr(module, class_name, None)
    if cls is None:
        raise ConfigError(f"module {module_name!r} has no class {class_name!r}")
    if not (isinstance(cls, type) and issubclass(cls, Node)):
        raise ConfigError(f"{path} is not a tether Node")
    if cls is Node:                 # it ran: no inputs, no outputs, nothing to do until stopped
        raise ConfigError(f"{path} is the base class of nodes: give a node class (a subclass of it)")
    return cls


def apply_rt_priority(priority: int, node_id: str = "") -> int:
    """Put the calling thread -- and the threads it starts afterwards, ZeroMQ's among them -- under
    ``SCHED_FIFO`` at ``priority``; return the priority it runs at (0: normal scheduling).

    The kernel keeps 5 % of each second for other tasks (``sched_rt_runtime_us``), so a node that
    spins cannot lock the machine up; a node meant for this sleeps between its cycles.
    """
    if priority <= 0:
        return 0
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError as exc:
        log.warning("%s: rt_priority %d not applied (%s): running with normal scheduling; grant the user "
                    "CAP_SYS_NICE or an rtprio limit (limits.conf)", node_id or "node", priority,
                    exc.strerror or exc)
        return 0
    log.info("%s: running SCHED_FIFO at priority %d", node_id or "node", priority)
    return priority


def run_spec(spec: RunSpec, *, install_signals: bool = True) -> int:
    """Run one node until SIGINT/SIGTERM; return its exit code."""
    node_cls = load_node_class(spec.node)
    apply_rt_priority(spec.rt_priority, spec.node_id)    # before any thread starts: they inherit it
    runtime = NodeRuntime(spec, node_cls)
    if install_signals:
        def on_signal(signum: int, frame: Any) -> None:
            runtime.stop()
        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
        watch_parent(spec.parent_pid, runtime.stop)
    code = runtime.serve()
    if spec.parent_pid:              # launched: one line the launcher takes, not prints (its stop count)
        try:
            print(STOP_REPORT_TEXT + json.dumps(runtime.stop_report()), flush=True)
        except (OSError, ValueError):    # the launcher is gone (a broken pipe, a closed stream): no one to tell
            pass
    # Terminate ZeroMQ before the interpreter tears objects down: zero-copy frames still queued
    # (within the linger time) must not outlive the buffers they point into.
    runtime.ctx.term()
    return code


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT, stream=sys.stderr)
    faulthandler.enable(all_threads=True)      # a crash in native code leaves its Python stack in the log
    faulthandler.register(signal.SIGUSR1, all_threads=True)   # and the launcher asks for stacks with SIGUSR1
    if not argv:
        print("usage: python -m tether.runner -   (RunSpec JSON on stdin)", file=sys.stderr)
        return 2
    try:
        spec = msgspec.convert(read_spec_arg(argv[0]), RunSpec)
        return run_spec(spec)
    except (ConfigError, ValueError, msgspec.ValidationError) as exc:
        logging.getLogger("tether").error("%s", exc)
        return 2


if __name__ == "__main__":
    sys.exit(main())
