"""Entry point of one node process: ``python -m tether.runner SPEC_JSON`` (the launcher's child)."""
from __future__ import annotations

import importlib
import json
import logging
import signal
import sys
from typing import Any

import msgspec

from tether.errors import ConfigError
from tether.node import Node
from tether.runtime import NodeRuntime, RunSpec

LOG_FORMAT = "%(levelname)s %(name)s: %(message)s"


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
    return cls


def run_spec(spec: RunSpec, *, install_signals: bool = True) -> int:
    """Run one node until SIGINT/SIGTERM; return its exit code."""
    node_cls = load_node_class(spec.node)
    runtime = NodeRuntime(spec, node_cls)
    if install_signals:
        def on_signal(signum: int, frame: Any) -> None:
            runtime.stop()
        signal.signal(signal.SIGTERM, on_signal)
        signal.signal(signal.SIGINT, on_signal)
    code = runtime.serve()
    # Terminate ZeroMQ before the interpreter tears objects down: zero-copy frames still queued
    # (within the linger time) must not outlive the buffers they point into.
    runtime.ctx.term()
    return code


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT, stream=sys.stderr)
    if not argv:
        print("usage: python -m tether.runner SPEC_JSON", file=sys.stderr)
        return 2
    try:
        spec = msgspec.convert(json.loads(argv[0]), RunSpec)
        return run_spec(spec)
    except ConfigError as exc:
        logging.getLogger("tether").error("%s", exc)
        return 2


if __name__ == "__main__":
    sys.exit(main())
