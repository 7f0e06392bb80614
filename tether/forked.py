"""Node processes forked from the launcher, which has already imported every node class.

A fresh interpreter per node re-imports numpy, ZeroMQ, msgspec and the node's module
(about 0.3 s of CPU each: 50 nodes on two cores is most of the start-up). The launcher
has imported all of them while validating the launch file and holds no ZeroMQ context,
so a fork starts a node in milliseconds. The child leaves the launcher's session, gets a
pipe as stdout and stderr, the node's own environment, fresh logging, and runs
:func:`tether.runner.run_spec`; it never returns into the launcher's code.

``TETHER_SPAWN=exec``, a platform without ``fork``, or a launcher that imported a library whose
threads do not survive a fork (:data:`FORK_UNSAFE`) starts ``python -m tether.runner`` instead.
"""
from __future__ import annotations

import faulthandler
import logging
import os
import signal
import subprocess
import sys
import time
import traceback
from typing import IO

from tether.runtime import RunSpec


#: libraries whose thread pools do not survive a fork: a launcher that imported one (validating a
#: node that uses it) starts fresh interpreters instead
FORK_UNSAFE = ("jax", "jaxlib", "torch", "tensorflow")
STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}


def can_fork() -> bool:
    return (hasattr(os, "fork") and os.environ.get("TETHER_SPAWN", "fork") != "exec"
            and not any(name in sys.modules for name in FORK_UNSAFE))


class ForkedNode:
    """The part of ``subprocess.Popen`` the supervisor uses, for a node forked from this process."""

    def __init__(self, spec: RunSpec, env: dict[str, str]) -> None:
        read, write = os.pipe()
        # Stop signals wait until the child has its own handlers: one that arrived between the
        # fork and then would run the launcher's handler in the child, and the node never stop.
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            pid = os.fork()
        except BaseException:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
            raise
        if pid == 0:
            code = 70
            try:
                os.close(read)
                code = _run_child(spec, env, write, mask)
            except BaseException:      # noqa: BLE001 - the child must never run on in the launcher's code
                try:
                    traceback.print_exc()
                except BaseException:  # noqa: BLE001
                    pass
            finally:
                os._exit(code)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        os.close(write)
        self.pid = pid
        self.returncode: int | None = None
        self.stdout: IO[str] = os.fdopen(read, "r", errors="replace")

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:
                self.returncode = -signal.SIGKILL     # reaped elsewhere: gone, cause unknown
                return self.returncode
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(f"node pid {self.pid}", timeout)
            time.sleep(0.005)
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, sig)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


def _drop_inherited_fds(keep: int) -> None:
    """Point every descriptor above stderr that the launcher had open, except ``keep``, at /dev/null.

    ``subprocess`` closes them; a fork keeps them: the read ends of earlier siblings' and the
    recorder's pipes, the launcher's files. A sibling holding a node's pipe open turns a dead
    launcher's broken pipe (an error the node sees) into a full one (a write that blocks). They
    are replaced rather than closed because launcher objects in this memory still own those
    numbers: closing one later (a collected file object) must not close a socket of the node's
    that reused the number.
    """
    null = os.open(os.devnull, os.O_RDWR)
    try:
        fds = [int(name) for name in os.listdir("/proc/self/fd")]
    except OSError:                                # not Linux: every number up to the limit
        fds = list(range(3, min(os.sysconf("SC_OPEN_MAX"), 4096)))
    for fd in fds:
        if fd <= 2 or fd in (keep, null):
            continue
        try:
            os.fstat(fd)                           # open? (the listing's own descriptor is gone by now)
        except OSError:
            continue
        os.dup2(null, fd, inheritable=False)
    os.close(null)


def _run_child(spec: RunSpec, env: dict[str, str], out_fd: int, mask: set) -> int:
    """In the forked child: become a node process like ``python -m tether.runner`` would be."""
    _drop_inherited_fds(keep=out_fd)
    os.setsid()                                    # Ctrl-C in the terminal reaches the launcher only
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)         # a stop before the node's own handlers: just exit
    signal.pthread_sigmask(signal.SIG_SETMASK, mask)
    os.dup2(out_fd, 1)
    os.dup2(out_fd, 2)
    os.close(out_fd)
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)
    os.close(null)
    os.environ.clear()
    os.environ.update(env)
    # New stream objects: the inherited ones may have been locked by a launcher thread at the fork.
    sys.stdout = open(1, "w", buffering=1, errors="backslashreplace", closefd=False)
    sys.stderr = open(2, "w", buffering=1, errors="backslashreplace", closefd=False)
    from tether import runtime, transport
    from tether.errors import ConfigError
    from tether.runner import LOG_FORMAT, run_spec

    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT, stream=sys.stderr, force=True)
    faulthandler.enable(file=sys.stderr, all_threads=True)
    faulthandler.register(signal.SIGUSR1, file=sys.stderr, all_threads=True)   # the launcher asks for stacks
    try:
        transport.reload_env()                      # this node's own TETHER_* knobs, not the launcher's
        runtime.PUB_QUEUE_BYTES = transport.PUB_QUEUE_BYTES
        return run_spec(spec)
    except (ConfigError, ValueError) as exc:
        logging.getLogger("tether").error("%s", exc)
        return 2
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
