"""ZeroMQ transport: endpoints, CurveZMQ keys, and the frame layout ``[topic, body, *buffers]``.

Frame 0 is the exact topic ``<node-id>/<output>``. ZeroMQ subscriptions match by
prefix, so receivers compare frame 0 for equality (``cam/image`` never delivers
``cam/image_raw``).
"""
from __future__ import annotations

import errno
import os
import socket
import stat
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zmq

from tether.errors import ConfigError

def _env_bytes(name: str, default: int) -> int:
    """A byte budget from the environment (a deployment knob, per node via a launch file's ``env``)."""
    text = os.environ.get(name, "")
    if not text:
        return default
    if not text.isdigit() or not 1024 <= int(text) <= 1 << 31:
        raise ConfigError(f"{name}={text!r}: an integer number of bytes in [1024, 2^31]")
    return int(text)


#: Largest message a node accepts (bytes, all frames; ``TETHER_MAX_MESSAGE_BYTES``, default
#: 1 GiB); larger ones are dropped by ZeroMQ (and the connection redialled, see :class:`LinkWatch`).
MAX_MESSAGE_BYTES = _env_bytes("TETHER_MAX_MESSAGE_BYTES", 1 << 30)
#: Bytes a publisher lets wait per subscriber (``TETHER_PUB_QUEUE_BYTES``, default 64 MiB): its
#: send high-water mark follows the largest message it has sent (ZeroMQ bounds queues in
#: messages only; 1000 x 4 MiB would be 4 GB). Past it, messages to that subscriber are
#: dropped (the subscriber counts them as a seq gap).
PUB_QUEUE_BYTES = _env_bytes("TETHER_PUB_QUEUE_BYTES", 64 << 20)
HWM_MAX = 1000
REDIAL_WAIT_NS = 1_000_000_000     # longest a dropped connection waits for its socket to be read empty


def reload_env() -> None:
    """Read the two byte budgets again (a node forked from its launcher, with its own environment)."""
    global MAX_MESSAGE_BYTES, PUB_QUEUE_BYTES
    MAX_MESSAGE_BYTES = _env_bytes("TETHER_MAX_MESSAGE_BYTES", 1 << 30)
    PUB_QUEUE_BYTES = _env_bytes("TETHER_PUB_QUEUE_BYTES", 64 << 20)


def hwm_for(budget_bytes: int, message_bytes: int) -> int:
    """A ZeroMQ high-water mark (messages) that keeps ``budget_bytes`` of ``message_bytes`` messages."""
    return max(2, min(HWM_MAX, budget_bytes // max(message_bytes, 1)))


def runtime_dir() -> Path:
    """Where ipc sockets and the registry of running graphs live (``$TETHER_RUNTIME_DIR`` overrides).

    Created 0700; an existing one must be a real directory owned by this user and writable by
    no one else (the rule ssh and ``XDG_RUNTIME_DIR`` users apply): in the shared temp folder,
    a directory planted by another user would otherwise host this graph's sockets.
    """
    base = os.environ.get("TETHER_RUNTIME_DIR") or os.path.join(tempfile.gettempdir(), f"tether-{os.getuid()}")
    path = Path(base)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        path.mkdir(mode=0o700)
    except FileExistsError:
        pass
    check_private_dir(path)
    return path


def check_private_dir(path: Path) -> None:
    """``ConfigError`` (one line naming the fix) unless ``path`` is a directory only this user controls."""
    info = path.lstat()
    if stat.S_ISLNK(info.st_mode):
        raise ConfigError(f"runtime directory {path} is a symlink: remove it (or set TETHER_RUNTIME_DIR to a "
                          f"directory of your own, mode 0700)")
    if not stat.S_ISDIR(info.st_mode):
        raise ConfigError(f"runtime directory {path} is not a directory: remove it")
    if info.st_uid != os.getuid():
        raise ConfigError(f"runtime directory {path} belongs to uid {info.st_uid}, not to you: remove it or set "
                          f"TETHER_RUNTIME_DIR to a directory of your own (mode 0700)")
    if info.st_mode & 0o022:
        raise ConfigError(f"runtime directory {path} is writable by others (mode {stat.S_IMODE(info.st_mode):o}): "
                          f"run: chmod 700 {path}")


def private_subdir(name: str) -> Path:
    """``runtime_dir()/name``, created 0700; an existing one passes the same checks as the runtime directory
    (one planted while the runtime directory was open to others would otherwise be used as it is)."""
    folder = runtime_dir() / name
    try:
        folder.mkdir(mode=0o700)
    except FileExistsError:
        pass
    check_private_dir(folder)
    return folder


def free_port_base(count: int = 1, host: str = "127.0.0.1", *, seed: int | None = None) -> int:
    """A port ``p`` such that ``p .. p + count - 1`` can be bound on ``host`` now: a machine's
    ``port_base`` for tests and tools that launch graphs side by side.

    Chosen below the kernel's ephemeral range (``ip_local_port_range``): a port the kernel
    handed out (``bind(0)``) sits in that range, where any outgoing connection -- one launcher
    dialling another -- may take the next ports before the graph binds them (CI: a node failed
    with "address already in use" on its port_base + 1).
    """
    import random

    try:
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        low = 32768                                  # Linux's default
    top = low - count
    if top <= 20000:
        raise RuntimeError(f"no room for {count} ports below the ephemeral range (starts at {low})")
    rng = random.Random(os.getpid() if seed is None else seed)   # two test processes start apart
    for _ in range(200):
        base = rng.randrange(20000, top)
        held = []
        try:
            for port in range(base, base + count):
                sock = socket.socket()
                held.append(sock)
                sock.bind((host, port))
            return base
        except OSError:
            continue
        finally:
            for sock in held:
                sock.close()
    raise RuntimeError(f"no {count} free consecutive ports found on {host} in 200 tries")


def ipc_endpoint(graph: str, node_id: str, token: str) -> str:
    """A same-host endpoint for ``node_id`` (unix socket paths must stay short: ~100 bytes)."""
    folder = private_subdir("s")
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in f"{graph}.{node_id}")[:40]
    return f"ipc://{folder}/{safe}.{token}"


def sweep_stale_sockets() -> int:
    """Remove ipc socket files nobody listens on (left by a node killed with SIGKILL); return how many.

    A socket file whose listener is gone refuses connections; one that is alive accepts
    (and the probe closes at once, which ZeroMQ takes as a peer that left).
    """
    folder = private_subdir("s")
    removed = 0
    for path in folder.glob("*"):
        try:
            if not stat.S_ISSOCK(path.lstat().st_mode):
                continue
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
                probe.connect(str(path))
        except ConnectionRefusedError:
            path.unlink(missing_ok=True)
            removed += 1
        except OSError:
            continue
    return removed


@dataclass(frozen=True)
class CurveKeys:
    """One machine's CurveZMQ identity: its own key pair and the public keys of the graph's machines.

    Publishers serve with the pair and accept only subscribers whose key is in ``peers``
    (the allow-list); subscribers dial a publisher with its machine's public key. See
    :mod:`tether.keystore` for where they are kept.
    """

    public: bytes
    secret: bytes
    peers: dict[str, bytes]        # machine -> public key (z85)

    def to_json(self) -> dict[str, Any]:
        return {"public": self.public.decode(), "secret": self.secret.decode(),
                "peers": {m: k.decode() for m, k in self.peers.items()}}

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> "CurveKeys":
        return cls(doc["public"].encode(), doc["secret"].encode(), {m: k.encode() for m, k in doc["peers"].items()})

    @classmethod
    def generate(cls, machines: tuple[str, ...] = ("local",)) -> "CurveKeys":
        """A fresh pair for the first of ``machines`` (others get pairs whose secrets are thrown away): tests."""
        pairs = {m: zmq.curve_keypair() for m in machines}
        public, secret = pairs[machines[0]]
        return cls(public, secret, {m: pub for m, (pub, _) in pairs.items()})


def make_pub(ctx: zmq.Context, binds: list[str], curve: CurveKeys | None) -> zmq.Socket:
    """The node's one publisher: an XPUB (so it can see subscriptions arrive) bound to ``binds``."""
    sock = ctx.socket(zmq.XPUB)
    sock.setsockopt(zmq.XPUB_VERBOSE, 1)       # every subscribe reaches us, not only the first per topic
    sock.setsockopt(zmq.XPUB_VERBOSER, 1)      # and every unsubscribe (a subscriber leaving, too): exact counts
    sock.setsockopt(zmq.SNDHWM, HWM_MAX)
    sock.setsockopt(zmq.LINGER, 500)
    if curve is not None:
        sock.curve_server = True
        sock.curve_secretkey = curve.secret
        sock.curve_publickey = curve.public
    for endpoint in binds:
        try:
            sock.bind(endpoint)
        except zmq.ZMQError as exc:
            sock.close(linger=0)
            if exc.errno == errno.EADDRINUSE:
                raise ConfigError(f"cannot bind {endpoint}: the address is in use by another process (another "
                                  "launch of this graph, or a port the system handed out); stop it, or give "
                                  "this machine another port_base") from None
            raise ConfigError(f"cannot bind {endpoint}: {exc.strerror}") from None
    return sock


def make_sub(ctx: zmq.Context, rcvhwm: int = HWM_MAX) -> zmq.Socket:
    """A SUB socket; its receive high-water mark is set here, before any connect, never after:
    changing a high-water mark on a socket with live pipes races ZeroMQ's I/O thread (libzmq
    4.3.5: a null call in ZMQbg/IO when a pipe was being torn down, seen in multi-robot runs)."""
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.RCVHWM, rcvhwm)
    sock.setsockopt(zmq.MAXMSGSIZE, MAX_MESSAGE_BYTES)
    sock.setsockopt(zmq.LINGER, 0)
    return sock


def connect_sub(sock: zmq.Socket, endpoint: str, curve: CurveKeys | None, server_key: bytes | str = b"") -> None:
    """Connect ``sock`` to a publisher; a Curve-server publisher needs ``curve`` and its ``server_key``.

    Curve options apply to connections made after they are set, so one socket can dial
    publishers of several machines (each with its own key); a socket that mixes secured tcp
    and plain ipc publishers gets a dedicated socket (see :class:`Subscriptions`).
    """
    if curve is not None:
        if not server_key:
            raise ValueError(f"no server key for the secured publisher at {endpoint}")
        sock.curve_serverkey = server_key.encode() if isinstance(server_key, str) else server_key
        sock.curve_publickey = curve.public
        sock.curve_secretkey = curve.secret
    sock.connect(endpoint)


class Subscriptions:
    """SUB sockets for a set of topics: one plain, one for Curve-server publishers (Curve is per socket).

    Each endpoint is connected once per socket, each topic subscribed exactly.
    """

    def __init__(self, ctx: zmq.Context, curve: CurveKeys | None = None, *,
                 rcvhwm: dict[bool, int] | None = None) -> None:
        self.ctx, self.curve = ctx, curve
        self.rcvhwm = rcvhwm or {}                 # per kind (secure or not): the sockets' receive HWM
        self._plain: zmq.Socket | None = None
        self._secure: zmq.Socket | None = None
        self._connected: set[tuple[str, bool]] = set()
        self.endpoints: dict[zmq.Socket, set[str]] = {}

    @staticmethod
    def kind(curve: CurveKeys | None, secure: bool) -> bool:
        """Which socket an input lands on: the Curve one (True) or the plain one."""
        return curve is not None and secure

    def rcvhwm_of(self, sock: zmq.Socket) -> int:
        return self.rcvhwm.get(sock is self._secure, HWM_MAX)

    def add(self, topic: str, endpoint: str, *, secure: bool = False, server_key: bytes | str = b"") -> zmq.Socket:
        use_curve = self.kind(self.curve, secure)
        if use_curve:
            self._secure = sock = self._secure or make_sub(self.ctx, self.rcvhwm.get(True, HWM_MAX))
        else:
            self._plain = sock = self._plain or make_sub(self.ctx, self.rcvhwm.get(False, HWM_MAX))
        if (endpoint, use_curve) not in self._connected:
            connect_sub(sock, endpoint, self.curve if use_curve else None, server_key)
            self._connected.add((endpoint, use_curve))
            self.endpoints.setdefault(sock, set()).add(endpoint)
        sock.setsockopt(zmq.SUBSCRIBE, topic.encode())
        return sock

    @property
    def sockets(self) -> list[zmq.Socket]:
        return [s for s in (self._plain, self._secure) if s is not None]


class LinkWatch:
    """Redials a publisher whose connection ZeroMQ dropped, and says which and why.

    libzmq (4.3) closes a connection that carries a frame over ``MAXMSGSIZE`` and, that
    being a protocol error, never dials it again: one oversize frame would cut the input
    for good. Disconnecting and connecting the endpoint again restores it (measured: the
    frames sent after the oversize one arrive again within one check period). A publisher
    that simply went away is redialled the same way, which ZeroMQ would have done anyway.
    A connection that fails its security handshake (a plain socket dialling a CurveZMQ
    publisher, or keys from another keystore) is reported as such: redialling cannot mend it.

    ``zmq_disconnect`` discards what the dropped connection delivered and the node has not
    read yet (the last messages of a publisher that stopped): the redial waits until the
    socket has nothing left to read, or :data:`REDIAL_WAIT_NS` at most (a socket that other
    publishers keep busy). :attr:`gone` holds the endpoints whose connection dropped and has
    not come back (a stopping node takes them as finished: :meth:`NodeRuntime.serve`).
    """

    HANDSHAKE_FAILED = (zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
                        | zmq.EVENT_HANDSHAKE_FAILED_AUTH)

    def __init__(self, sockets: list[zmq.Socket], endpoints: dict[zmq.Socket, set[str]]) -> None:
        events = zmq.EVENT_DISCONNECTED | zmq.EVENT_HANDSHAKE_SUCCEEDED | self.HANDSHAKE_FAILED
        self._watch = [(sock, sock.get_monitor_socket(events), endpoints.get(sock, set())) for sock in sockets]
        self._refused: set[tuple[int, str]] = set()   # (socket index, endpoint) whose handshake failed, until its drop
        self._due: dict[tuple[int, str], tuple[int, bool]] = {}   # dropped, not redialled yet -> (when ns, refused)
        self.gone: set[str] = set()

    def poll(self, *, redial: bool = True) -> list[tuple[str, bool]]:
        """Take in the connections' events and redial (unless ``redial`` is False) the endpoints
        dropped whose socket has been read empty; return them, one ``(endpoint, handshake_failed)``
        per redial."""
        from zmq.utils.monitor import recv_monitor_message

        now = time.monotonic_ns()
        for k, (sock, monitor, known) in enumerate(self._watch):
            while monitor.poll(0):
                event = recv_monitor_message(monitor)
                endpoint = event["endpoint"].decode(errors="replace")
                if endpoint not in known:
                    continue       # not one we dialled (a bind-side peer): nothing to redial
                if event["event"] & zmq.EVENT_HANDSHAKE_SUCCEEDED:
                    self.gone.discard(endpoint)
                elif event["event"] & self.HANDSHAKE_FAILED:
                    self._refused.add((k, endpoint))      # its DISCONNECTED follows, maybe in a later call
                else:
                    self.gone.add(endpoint)
                    self._due.setdefault((k, endpoint), (now, False))
                    if (k, endpoint) in self._refused:
                        self._due[k, endpoint] = (self._due[k, endpoint][0], True)
                        self._refused.discard((k, endpoint))
        if not redial:
            return []
        redialled = []
        for (k, endpoint), (when_ns, refused) in list(self._due.items()):
            sock = self._watch[k][0]
            if now - when_ns < REDIAL_WAIT_NS and sock.poll(0, zmq.POLLIN):
                continue           # read what it delivered first: disconnecting would discard it
            del self._due[k, endpoint]
            try:
                sock.disconnect(endpoint)
            except zmq.ZMQError:
                pass               # already forgotten by ZeroMQ: connecting again is still right
            sock.connect(endpoint)
            redialled.append((endpoint, refused))
        return redialled

    def close(self) -> None:
        for sock, monitor, _ in self._watch:
            try:
                sock.disable_monitor()
            except zmq.ZMQError:
                pass
            monitor.close(linger=0)
        self._watch = []


def start_authenticator(ctx: zmq.Context, curve: CurveKeys) -> Any:
    """ZAP handler accepting only the graph's machines' keys (authentication, not just encryption)."""
    from zmq.auth.thread import ThreadAuthenticator

    allowed = frozenset(curve.peers.values())

    class _Keys:
        def callback(self, domain: str, key: bytes) -> bool:
            return key in allowed                  # pyzmq hands the client key z85-encoded

    auth = ThreadAuthenticator(ctx)
    auth.start()
    auth.configure_curve_callback(domain="*", credentials_provider=_Keys())
    return auth
