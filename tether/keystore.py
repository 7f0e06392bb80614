"""Per-machine CurveZMQ keystores, as SROS2 keeps them: one key pair per machine, an allow-list of public keys.

A graph's keystore is a folder (``$TETHER_KEYS_DIR/<graph>/``, default
``~/.config/tether/keys/<graph>/``)::

    peers.json        {"machine": "<public key>", ...}   public: copy it to every machine
    <machine>.key     {"machine", "public", "secret"}     secret: mode 0600, on that machine only

A publisher answers only subscribers whose public key is in ``peers.json`` (ZAP), and a
subscriber checks the publisher's key against it (CurveZMQ server authentication), so a
machine that is compromised gives away its own key pair and nothing else: remove its line
from ``peers.json`` on the others and it is out.
"""
from __future__ import annotations

import fcntl
import json
import logging
import os
import re
import stat
from pathlib import Path

import zmq

from tether.errors import ConfigError
from tether.transport import CurveKeys

log = logging.getLogger("tether.keys")
PEERS = "peers.json"
NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")     # a graph or machine name, as a launch file has it


def _name(text: str, what: str) -> str:
    """A name that becomes a file or folder name: '../x' or 'a/b' would write outside the keystore."""
    if not NAME_RE.match(text):
        raise ConfigError(f"{what} {text!r}: a name is letters, digits, '-' or '_', starting with a letter "
                          "(as in the launch file)")
    return text


def keys_root() -> Path:
    return Path(os.environ.get("TETHER_KEYS_DIR") or Path.home() / ".config" / "tether" / "keys")


def keystore_dir(graph: str, override: str | Path | None = None) -> Path:
    """The keystore folder of ``graph`` (``override`` wins: ``--keys DIR``)."""
    return Path(override) if override else keys_root() / _name(graph, "graph")


def check_private(path: Path) -> None:
    """Refuse a secret file others could read or swap (the ssh rule); one line naming the fix."""
    info = path.lstat()
    if stat.S_ISLNK(info.st_mode):
        raise ConfigError(f"{path}: a secret key file must not be a symlink")
    if info.st_uid != os.getuid():
        raise ConfigError(f"{path}: owned by uid {info.st_uid}, not by you: refusing to use its secret key")
    if info.st_mode & 0o077:
        raise ConfigError(f"{path}: secret key readable by others (mode {stat.S_IMODE(info.st_mode):o}); "
                          f"run: chmod 600 {path}")


def _write_new(path: Path, text: str, mode: int) -> bool:
    """Create ``path`` exclusively (never through a symlink); False if it already exists."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), mode)
    except FileExistsError:
        return False
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    return True


def init(folder: Path, machines: list[str]) -> list[str]:
    """Create a key pair per machine (missing ones only) and the allow-list; return the machines created."""
    if not machines:
        raise ConfigError("a keystore needs at least one machine")
    for machine in machines:
        _name(machine, "machine")
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    peers = read_peers(folder) if (folder / PEERS).exists() else {}
    created = []
    for machine in machines:
        if machine in peers:
            continue
        public, secret = zmq.curve_keypair()
        doc = {"machine": machine, "public": public.decode(), "secret": secret.decode()}
        if _write_new(folder / f"{machine}.key", json.dumps(doc), 0o600):
            peers[machine] = public.decode()
            created.append(machine)
        else:
            raise ConfigError(f"{folder / f'{machine}.key'} exists but {machine} is not in {folder / PEERS}: "
                              f"add its public key there or remove the file")
    tmp = folder / f".{PEERS}.{os.getpid()}"
    tmp.unlink(missing_ok=True)
    _write_new(tmp, json.dumps(peers, indent=1, sort_keys=True), 0o644)
    os.replace(tmp, folder / PEERS)
    return created


def read_peers(folder: Path) -> dict[str, str]:
    try:
        doc = json.loads((folder / PEERS).read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"cannot read the allow-list {folder / PEERS}: {exc}") from None
    if not isinstance(doc, dict) or not all(isinstance(k, str) and isinstance(v, str) and len(v) == 40
                                            for k, v in doc.items()):
        raise ConfigError(f"{folder / PEERS}: expected {{machine: 40-character z85 public key}}")
    return doc


def load(folder: Path, machine: str) -> CurveKeys:
    """This machine's key pair and the graph's allow-list; ``ConfigError`` saying what to copy where."""
    peers = read_peers(folder)
    path = folder / f"{machine}.key"
    if not path.exists():
        raise ConfigError(f"no secret key for machine {machine!r} in {folder}: copy {machine}.key there from the "
                          f"machine where you ran 'tether keys init' (mode 0600)")
    check_private(path)
    try:
        doc = json.loads(path.read_text())
        public, secret = doc["public"], doc["secret"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"cannot read {path}: {exc}") from None
    if peers.get(machine) != public:
        raise ConfigError(f"{path}: its public key is not {machine!r}'s in {folder / PEERS}; "
                          f"the two files come from different keystores")
    return CurveKeys(public.encode(), secret.encode(), {m: k.encode() for m, k in peers.items()})


def ensure(folder: Path, machines: list[str], machine: str) -> CurveKeys:
    """Load ``machine``'s keys, creating the whole keystore first when there is none (one host, first run)."""
    legacy = folder.with_suffix(".json")
    if legacy.is_file():
        log.warning("%s is an old shared-key file and is no longer used (one key pair per machine now: %s); "
                    "delete it", legacy, folder)
    if not (folder / PEERS).exists():
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        fd = os.open(folder / ".lock", os.O_WRONLY | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)      # two launchers of one graph starting together make one keystore
            if not (folder / PEERS).exists():
                init(folder, machines)
                log.info("created keystore %s for %s: on another host copy peers.json and only that host's "
                         "<machine>.key (see README, Security)", folder, ", ".join(machines))
        finally:
            os.close(fd)
    return load(folder, machine)
