"""ZeroMQ transport: endpoints, CurveZMQ keys, and the frame layout ``[topic, body, *buffers]``.

Frame 0 is the exact topic ``<node-id>/<output>``. ZeroMQ subscriptions match by
prefix, so receivers compare frame 0 for equality (``cam/image`` never delivers
``cam/image_raw``).
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zmq

#: Largest message a node accepts (bytes, all frames); larger ones are dropped by ZeroMQ
#: (and the connection redialled, see :class:`LinkWatch`).
MAX_MESSAGE_BYTES = 1 << 30
#: Bytes a publisher lets wait per subscriber: its send high-water mark follows the largest
#: message it has sent (ZeroMQ bounds queues in messages only; 1000 x 4 MiB would be 4 GB).
PUB_QUEUE_BYTES = 64 << 20
HWM_MAX = 1000


def hwm_for(budget_bytes: int, message_bytes: int) -> int:
    """A ZeroMQ high-water mark (messages) that keeps ``budget_bytes`` of ``message_bytes`` messages."""
    return max(2, min(HWM_MAX, budget_bytes // max(message_bytes, 1)))


def runtime_dir() -> Path:
    """Where ipc sockets and the registry of running graphs live (``$TETHER_RUNTIME_DIR`` overrides)."""
    base = os.environ.get("TETHER_RUNTIME_DIR") or os.path.join(tempfile.gettempdir(), f"tether-{os.getuid()}")
    path = Path(base)
    path.mkdir(parents=True, exist_ok=True, mode=0o700)
    return path


def ipc_endpoint(graph: str, node_id: str, token: str) -> str:
    """A same-host endpoint for ``node_id`` (unix socket paths must stay short: ~100 bytes)."""
    folder = runtime_dir() / "s"
    folder.mkdir(exist_ok=True)
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in f"{graph}.{node_id}")[:40]
    return f"ipc://{folder}/{safe}.{token}"


@dataclass(frozen=True)
class CurveKeys:
    """A graph's CurveZMQ keys: the server pair every publisher uses, the client pair every subscriber uses."""

    server_public: bytes
    server_secret: bytes
    client_public: bytes
    client_secret: bytes

    @classmethod
    def generate(cls) -> "CurveKeys":
        spub, ssec = zmq.curve_keypair()
        cpub, csec = zmq.curve_keypair()
        return cls(spub, ssec, cpub, csec)

    def to_json(self) -> dict[str, str]:
        return {k: getattr(self, k).decode() for k in ("server_public", "server_secret", "client_public", "client_secret")}

    @classmethod
    def from_json(cls, doc: dict[str, str]) -> "CurveKeys":
        return cls(**{k: v.encode() for k, v in doc.items()})

    @classmethod
    def load_or_create(cls, path: Path) -> "CurveKeys":
        """Keys of one graph, kept in ``path`` (mode 0600) so every machine of the graph shares them."""
        if path.exists():
            return cls.from_json(json.loads(path.read_text()))
        keys = cls.generate()
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as fh:
            json.dump(keys.to_json(), fh)
        try:
            os.link(tmp, path)      # atomic and exclusive: two launchers starting together agree on one key set
        except FileExistsError:
            pass
        finally:
            os.unlink(tmp)
        return cls.from_json(json.loads(path.read_text()))


def make_pub(ctx: zmq.Context, binds: list[str], curve: CurveKeys | None) -> zmq.Socket:
    """The node's one publisher: an XPUB (so it can see subscriptions arrive) bound to ``binds``."""
    sock = ctx.socket(zmq.XPUB)
    sock.setsockopt(zmq.XPUB_VERBOSE, 1)       # every subscribe reaches us, not only the first per topic
    sock.setsockopt(zmq.SNDHWM, HWM_MAX)
    sock.setsockopt(zmq.LINGER, 500)
    if curve is not None:
        sock.curve_server = True
        sock.curve_secretkey = curve.server_secret
        sock.curve_publickey = curve.server_public
    for endpoint in binds:
        sock.bind(endpoint)
    return sock


def make_sub(ctx: zmq.Context) -> zmq.Socket:
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.RCVHWM, HWM_MAX)
    sock.setsockopt(zmq.MAXMSGSIZE, MAX_MESSAGE_BYTES)
    sock.setsockopt(zmq.LINGER, 0)
    return sock


def connect_sub(sock: zmq.Socket, endpoint: str, curve: CurveKeys | None) -> None:
    """Connect ``sock`` to a publisher; a Curve-server publisher needs ``curve`` (set before connect)."""
    if curve is not None:
        # Curve options apply to connections made after they are set; a socket that mixes
        # secured tcp and plain ipc publishers gets a dedicated socket (see NodeRuntime).
        sock.curve_serverkey = curve.server_public
        sock.curve_publickey = curve.client_public
        sock.curve_secretkey = curve.client_secret
    sock.connect(endpoint)


class Subscriptions:
    """SUB sockets for a set of topics: one plain, one for Curve-server publishers (Curve is per socket).

    Each endpoint is connected once per socket, each topic subscribed exactly.
    """

    def __init__(self, ctx: zmq.Context, curve: CurveKeys | None = None) -> None:
        self.ctx, self.curve = ctx, curve
        self._plain: zmq.Socket | None = None
        self._secure: zmq.Socket | None = None
        self._connected: set[tuple[str, bool]] = set()
        self.endpoints: dict[zmq.Socket, set[str]] = {}

    def add(self, topic: str, endpoint: str, *, secure: bool = False) -> zmq.Socket:
        use_curve = self.curve is not None and secure
        if use_curve:
            self._secure = sock = self._secure or make_sub(self.ctx)
        else:
            self._plain = sock = self._plain or make_sub(self.ctx)
        if (endpoint, use_curve) not in self._connected:
            connect_sub(sock, endpoint, self.curve if use_curve else None)
            self._connected.add((endpoint, use_curve))
            self.endpoints.setdefault(sock, set()).add(endpoint)
        sock.setsockopt(zmq.SUBSCRIBE, topic.encode())
        return sock

    @property
    def sockets(self) -> list[zmq.Socket]:
        return [s for s in (self._plain, self._secure) if s is not None]


class LinkWatch:
    """Redials a publisher whose connection ZeroMQ dropped, and says which.

    libzmq (4.3) closes a connection that carries a frame over ``MAXMSGSIZE`` and, that
    being a protocol error, never dials it again: one oversize frame would cut the input
    for good. Disconnecting and connecting the endpoint again restores it (measured: the
    frames sent after the oversize one arrive again within one check period). A publisher
    that simply went away is redialled the same way, which ZeroMQ would have done anyway.
    """

    def __init__(self, sockets: list[zmq.Socket], endpoints: dict[zmq.Socket, set[str]]) -> None:
        self._watch = [(sock, sock.get_monitor_socket(zmq.EVENT_DISCONNECTED), endpoints.get(sock, set()))
                       for sock in sockets]

    def poll(self) -> list[str]:
        """Redial every endpoint dropped since the last call; return them (one entry per drop)."""
        from zmq.utils.monitor import recv_monitor_message

        dropped = []
        for sock, monitor, known in self._watch:
            while monitor.poll(0):
                endpoint = recv_monitor_message(monitor)["endpoint"].decode(errors="replace")
                if endpoint not in known:
                    continue       # not one we dialled (a bind-side peer): nothing to redial
                try:
                    sock.disconnect(endpoint)
                except zmq.ZMQError:
                    pass           # already forgotten by ZeroMQ: connecting again is still right
                sock.connect(endpoint)
                dropped.append(endpoint)
        return dropped

    def close(self) -> None:
        for sock, monitor, _ in self._watch:
            try:
                sock.disable_monitor()
            except zmq.ZMQError:
                pass
            monitor.close(linger=0)
        self._watch = []


def start_authenticator(ctx: zmq.Context, curve: CurveKeys) -> Any:
    """ZAP handler accepting only the graph's client key (authentication, not just encryption)."""
    from zmq.auth.thread import ThreadAuthenticator

    class _Keys:
        def callback(self, domain: str, key: bytes) -> bool:
            return key == curve.client_public      # pyzmq hands the client key z85-encoded

    auth = ThreadAuthenticator(ctx)
    auth.start()
    auth.configure_curve_callback(domain="*", credentials_provider=_Keys())
    return auth
