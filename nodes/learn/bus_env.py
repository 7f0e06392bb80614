"""Gymnasium environments served by a Tether simulator node, stepped in lockstep over the bus.

>>> env = BusVecEnv("sim.car_env:ReachCar", n_envs=8)              # in-process, no sockets
>>> env = BusVecEnv("sim.car_env:MazeCar", n_envs=8, mode="ipc", shards=2)   # 2 node processes
>>> obs, info = env.reset(seed=0)
>>> obs, rew, term, trunc, info = env.step(env.action_space.sample())

The simulator is an ordinary node (:class:`nodes.learn.sim_node.SimNode`) holding N
instances of a :class:`~nodes.learn.vec_sim.VecSim`. The environment publishes one
``EnvReset`` or ``EnvAction`` and waits for the node's ``EnvStep``: no wall clock anywhere,
so the same seed and actions give bit-identical episodes in-process, over ipc, and when a
recorded episode is replayed (:func:`replay_log`). ``mode="inproc"`` calls the node's
handlers directly (messages as objects, no encoding); ``mode="ipc"`` runs it in its own
process(es) on real ZeroMQ sockets, ``shards`` processes each holding a slice of the
instances. A simulator process that dies or stops answering raises :class:`SimulatorError`
at once (its exit code and last log lines), never a hang.

``record="episode.mcap"`` writes every request and reply (and the simulator's spec) to an
MCAP log in virtual time; :func:`replay_log` re-runs the requests through a fresh simulator
and checks every reply is bit-identical.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import gymnasium
import msgspec
import numpy as np
import zmq
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from msgs.learn import EnvAction, EnvReset, EnvStep
from msgs.std import String
from nodes.learn.sim_node import SimNode, load_sim
from tether.codec import Codec
from tether.log import LogReader, LogWriter
from tether.message import Message
from tether.node import Context, Node
from tether.runtime import RunSpec, Source


class SimulatorError(RuntimeError):
    """The simulator died, stopped answering, or refused a request (the message says which)."""


class _Capture(Context):
    """The in-process runtime of a simulator node: publishing hands the reply back, nothing is sent."""

    def __init__(self) -> None:
        self.reply: Message | None = None

    def publish(self, node: Node, output: str, msg: Message) -> None:
        self.reply = msg

    def now_ns(self) -> int:
        return 0


class _InProc:
    def __init__(self, spec: dict[str, Any]) -> None:
        self.ctx = _Capture()
        self.node = SimNode(SimNode.make_config(spec), node_id="sim", context=self.ctx)
        self.node.setup()
        self.sim = self.node.sim

    def request(self, msgs: list[Message]) -> list[EnvStep]:
        out = []
        for msg in msgs:
            self.ctx.reply = None
            self.node.dispatch("reset" if isinstance(msg, EnvReset) else "action", msg)
            out.append(self.ctx.reply)
        return out

    def close(self) -> None:
        self.node.teardown()


class _Ipc:
    """Shards of the simulator in their own processes, on ipc sockets."""

    def __init__(self, specs: list[dict[str, Any]], timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self.codec = Codec()
        self.ctx = zmq.Context()
        self.dir = Path(tempfile.mkdtemp(prefix="tether-busenv-"))
        tag = uuid.uuid4().hex[:8]
        self.env_ep = f"ipc://{self.dir}/env"
        self.pub = self.ctx.socket(zmq.PUB)
        self.pub.bind(self.env_ep)
        self.sub = self.ctx.socket(zmq.SUB)
        self.seq: dict[bytes, int] = {}
        self.procs: list[subprocess.Popen] = []
        self.logs: list[Path] = []
        # one instance in this process, for the spaces and metric names only: the shards hold the real ones
        first = specs[0]
        self.sim = load_sim(first["sim"], 1, max_steps=first.get("max_steps", 0), params=first.get("params"))
        for k, spec in enumerate(specs):
            sim_ep = f"ipc://{self.dir}/sim{k}"
            run = RunSpec(graph=f"busenv-{tag}", node_id=f"sim{k}", node="nodes.learn.sim_node:SimNode",
                          params=spec, binds=[sim_ep], parent_pid=os.getpid(),
                          inputs={"reset": Source(topic=f"env/reset{k}", endpoint=self.env_ep),
                                  "action": Source(topic=f"env/action{k}", endpoint=self.env_ep)})
            log = self.dir / f"sim{k}.log"
            self.logs.append(log)
            with open(log, "wb") as err:
                proc = subprocess.Popen([sys.executable, "-m", "tether.runner", "-"], stdin=subprocess.PIPE,
                                        stdout=subprocess.DEVNULL, stderr=err, cwd=Path(__file__).resolve().parents[2])
            proc.stdin.write(msgspec.json.encode(run))
            proc.stdin.close()
            self.procs.append(proc)
            self.sub.connect(sim_ep)
            self.sub.subscribe(f"sim{k}/step".encode())
        self.poller = zmq.Poller()
        self.poller.register(self.sub, zmq.POLLIN)

    def _check_alive(self) -> None:
        for k, proc in enumerate(self.procs):
            code = proc.poll()
            if code is not None:
                tail = self.logs[k].read_text(errors="replace").strip().splitlines()[-5:]
                raise SimulatorError(f"simulator process sim{k} exited with code {code} mid-episode; "
                                     f"its last log lines: {' | '.join(tail) or '(none)'}")

    def _send(self, k: int, msg: Message) -> None:
        topic = f"env/{'reset' if isinstance(msg, EnvReset) else 'action'}{k}".encode()
        seq = self.seq.get(topic, 0) + 1
        self.seq[topic] = seq
        frames = self.codec.encode(msgspec.structs.replace(msg, seq=seq))
        self.pub.send(topic, zmq.SNDMORE)
        for i, f in enumerate(frames):
            self.pub.send(f, zmq.SNDMORE if i < len(frames) - 1 else 0, copy=i == 0)

    def request(self, msgs: list[Message]) -> list[EnvStep]:
        """Send shard k its message; gather the replies echoing (epoch, step). A reset is resent every
        0.1 s until answered (the node may not have subscribed yet): the node answers a repeat the same."""
        want = {k: (m.epoch, getattr(m, "step", 0)) for k, m in enumerate(msgs)}
        for k, m in enumerate(msgs):
            self._send(k, m)
        replies: dict[int, EnvStep] = {}
        deadline = time.monotonic() + self.timeout_s
        resend = time.monotonic() + 0.1
        while len(replies) < len(msgs):
            if self.poller.poll(20):
                while self.sub.poll(0):
                    frames = self.sub.recv_multipart(copy=False)
                    k = int(frames[0].bytes[3:frames[0].bytes.index(b"/")])    # b"sim3/step" -> 3
                    reply = self.codec.decode(EnvStep, [frames[1].bytes, *frames[2:]])
                    if want.get(k) == (reply.epoch, reply.step):
                        replies[k] = reply
                continue
            self._check_alive()
            now = time.monotonic()
            if now > deadline:
                raise SimulatorError(f"no reply from the simulator within {self.timeout_s:.0f} s "
                                     f"(shards waiting: {sorted(set(want) - set(replies))})")
            if isinstance(msgs[0], EnvReset) and now > resend:
                resend = now + 0.1
                for k, m in enumerate(msgs):
                    if k not in replies:
                        self._send(k, m)
        return [replies[k] for k in range(len(msgs))]

    def close(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in self.procs:
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
        self.pub.close(0)
        self.sub.close(0)
        self.ctx.term()
        for p in self.dir.iterdir():
            p.unlink(missing_ok=True)
        self.dir.rmdir()


def _split(n: int, shards: int) -> list[int]:
    base, extra = divmod(n, shards)
    return [base + (k < extra) for k in range(shards)]


class BusVecEnv(VectorEnv):
    """N simulator instances behind Gymnasium's vector API (same-step autoreset).

    ``infos`` holds ``final_obs`` with its mask ``_final_obs`` (the ended episodes' last
    observations), ``sim_time_s`` and the scenario's metrics by name (taken before autoreset).
    Actions: a Box's are clipped to its bounds; NaN or a discrete action out of range raises
    ``ValueError`` (the simulator refuses the whole step; nothing moves).
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, sim: str, n_envs: int = 1, *, mode: str = "inproc", shards: int = 1, max_steps: int = 0,
                 params: dict[str, Any] | None = None, record: str | Path | None = None, timeout_s: float = 30.0) -> None:
        if mode not in ("inproc", "ipc"):
            raise ValueError(f"mode must be 'inproc' or 'ipc', got {mode!r}")
        if not 1 <= shards <= n_envs or (mode == "inproc" and shards != 1):
            raise ValueError(f"shards must be in [1, n_envs] (1 in-process), got {shards} for {n_envs} instances")
        self.spec_params = {"sim": sim, "max_steps": max_steps, "params": dict(params or {})}
        counts = _split(n_envs, shards)
        specs = [{**self.spec_params, "n_envs": c} for c in counts]
        self._link = _InProc(specs[0]) if mode == "inproc" else _Ipc(specs, timeout_s)
        self.bounds = np.cumsum([0, *counts])
        self.num_envs, self.mode = n_envs, mode
        first = self._link.sim
        self.single_observation_space, self.single_action_space = first.observation_space, first.action_space
        self.observation_space = batch_space(self.single_observation_space, n_envs)
        self.action_space = batch_space(self.single_action_space, n_envs)
        self.metric_names = tuple(first.metric_names)
        self.dt_s = first.DT_S
        self._epoch, self._step, self._ticks = 0, 0, 0
        self._log: LogWriter | None = None
        if record is not None:
            self._log = LogWriter(record)
            self._log.write("env/spec", String(data=json.dumps({**self.spec_params, "n_envs": n_envs,
                                                                "shards": counts})), log_time_ns=0)

    @property
    def sim(self) -> Any:
        """The in-process simulator (to set scenario attributes such as an opponent policy)."""
        if self.mode != "inproc":
            raise AttributeError("the simulator runs in another process: only in-process envs expose .sim")
        return self._link.sim

    def _record(self, msgs: list[Message], replies: list[EnvStep]) -> None:
        if self._log is None:
            return
        # log time is simulation time: a step's request at t, its reply 1 ns before t + dt, when the
        # next request goes (no ties: a reader ordering by time alone keeps request before reply)
        t0 = self._ticks
        if isinstance(msgs[0], EnvAction):
            self._ticks += int(round(self.dt_s * 1e9))
        for k, (m, r) in enumerate(zip(msgs, replies)):
            kind = "reset" if isinstance(m, EnvReset) else "action"
            self._log.write(f"env/{kind}{k}", m, log_time_ns=t0)
            self._log.write(f"sim{k}/step", r, log_time_ns=max(self._ticks - 1, t0))

    def _exchange(self, msgs: list[Message]) -> EnvStep:
        replies = self._link.request(msgs)
        self._record(msgs, replies)
        refused = [r.error for r in replies if r.error]
        if refused:
            raise ValueError(f"the simulator refused the request: {refused[0]}")
        if len(replies) == 1:
            return replies[0]
        cat = {f: np.concatenate([getattr(r, f) for r in replies]) for f in
               ("sim_time_s", "obs", "final_obs", "rewards", "terminated", "truncated", "metrics")}
        return EnvStep(epoch=replies[0].epoch, step=replies[0].step, metric_names=replies[0].metric_names, **cat)

    def _infos(self, reply: EnvStep, done: np.ndarray) -> dict[str, Any]:
        infos: dict[str, Any] = {"sim_time_s": reply.sim_time_s, "final_obs": reply.final_obs, "_final_obs": done}
        for j, name in enumerate(reply.metric_names):
            infos[name] = reply.metrics[:, j]
        return infos

    def reset(self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every instance: an int seeds instance i with seed + i, a list one each, None continues."""
        super().reset(seed=seed if isinstance(seed, int) else None)
        if seed is None:
            seeds = np.full(self.num_envs, -1, np.int64)
        elif isinstance(seed, (int, np.integer)):
            seeds = int(seed) + np.arange(self.num_envs, dtype=np.int64)
        else:
            seeds = np.asarray(seed, np.int64)
            if seeds.shape != (self.num_envs,):
                raise ValueError(f"give one seed per instance ({self.num_envs}), got {seeds.shape}")
        self._epoch += 1
        self._step = 0
        msgs = [EnvReset(epoch=self._epoch, seeds=seeds[a:b]) for a, b in zip(self.bounds[:-1], self.bounds[1:])]
        reply = self._exchange(msgs)
        return reply.obs, self._infos(reply, np.zeros(self.num_envs, bool))

    def step(self, actions: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if self._epoch == 0:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions)
        if actions.shape[:1] != (self.num_envs,):
            raise ValueError(f"give one action per instance: shape ({self.num_envs}, ...), got {actions.shape}")
        self._step += 1
        msgs = [EnvAction(epoch=self._epoch, step=self._step, actions=actions[a:b])
                for a, b in zip(self.bounds[:-1], self.bounds[1:])]
        try:
            reply = self._exchange(msgs)
        except ValueError:
            self._step -= 1           # refused: nothing moved, the next action takes this step's place
            raise
        done = reply.terminated | reply.truncated
        return reply.obs, reply.rewards, reply.terminated, reply.truncated, self._infos(reply, done)

    def close_extras(self, **kwargs: Any) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None
        self._link.close()


class BusEnv(gymnasium.Env):
    """One simulator instance behind Gymnasium's single-environment API (no autoreset: after
    ``terminated`` or ``truncated`` call :meth:`reset`)."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, sim: str, **kwargs: Any) -> None:
        self.vec = BusVecEnv(sim, 1, **kwargs)
        self.observation_space = self.vec.single_observation_space
        self.action_space = self.vec.single_action_space
        self._done = True

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        obs, infos = self.vec.reset(seed=seed)
        self._done = False
        return obs[0], {k: v[0] for k, v in infos.items() if not k.startswith("_") and k != "final_obs"}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._done:
            raise RuntimeError("the episode has ended (or never started): call reset()")
        obs, rew, term, trunc, infos = self.vec.step(np.asarray(action)[None])
        self._done = bool(term[0] or trunc[0])
        info = {k: v[0] for k, v in infos.items() if not k.startswith("_") and k != "final_obs"}
        return infos["final_obs"][0], float(rew[0]), bool(term[0]), bool(trunc[0]), info

    def close(self) -> None:
        self.vec.close()


def _shard(topic: str) -> int:
    """The shard of ``env/action3`` or ``sim3/step``: 3."""
    return int(re.search(r"(\d+)(?:/step)?$", topic).group(1))


def replay_log(path: str | Path) -> dict[str, int]:
    """Re-run a recorded environment log's requests through fresh simulators; count replies that are
    bit-identical to the recorded ones (every field but the header). Raises ``ValueError`` on the first
    that is not, naming the topic and step."""
    reader = LogReader(path)
    spec_rec = next(reader.messages(["env/spec"]), None)
    if spec_rec is None:
        raise ValueError(f"{path}: no env/spec record (not written by BusVecEnv(record=...))")
    spec = json.loads(reader.decode(spec_rec).data)
    links = [_InProc({"sim": spec["sim"], "max_steps": spec["max_steps"], "params": spec["params"], "n_envs": c})
             for c in spec["shards"]]
    checked = 0
    pending: dict[int, EnvStep] = {}
    for rec in reader.messages():
        if rec.topic == "env/spec":
            continue
        msg = reader.decode(rec)
        if rec.topic.startswith("env/"):
            k = _shard(rec.topic)
            pending[k] = links[k].request([msg])[0]
            continue
        k = _shard(rec.topic)
        got = pending.pop(k)
        for name in msg.__struct_fields__:
            if name in ("stamp_ns", "seq", "frame_id"):
                continue
            a, b = getattr(msg, name), getattr(got, name)
            same = np.array_equal(a, b) and (not isinstance(a, np.ndarray) or a.dtype == b.dtype)
            if not same:
                raise ValueError(f"{path}: {rec.topic} epoch {msg.epoch} step {msg.step}: field {name} differs on replay")
        checked += 1
    return {"replies": checked, "instances": int(sum(spec["shards"]))}
