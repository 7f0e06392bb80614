"""Method (b) and the naive baseline of :mod:`nodes.slam.dslam`: block Gauss-Seidel on separator estimates.

Two-stage distributed Gauss-Seidel (Choudhary et al., IJRR 2017): chordal rotations, then
translations -- each a linear least-squares problem solved block by block, one block per
robot with its neighbours' separator estimates held -- then nonlinear block refinement with
the local LM solver. The naive baseline runs only the last stage, from each robot's own
odometry frame. A mixin of :class:`~nodes.slam.dslam.Agent`: it reads the agent's state.
"""
from __future__ import annotations

import logging
import math

import numpy as np

from nodes.slam.exchange import Candidate, Separators
from nodes.slam.pose_graph import GraphError, chordal_rotations, chordal_translations, optimize, wrap

log = logging.getLogger("nodes.slam.dslam")


class BlockGaussSeidel:
    """The ``dgs`` and ``block_gs`` rounds of an agent (see the module docstring)."""

    def _block_step(self) -> dict[int, Separators]:
        closures = self.accepted_closures()
        anchor = self.gauge_root == self.robot
        team = tuple(self.neighbours())
        if self.method == "dgs" and team != self._phase_team:
            self._phase_team = team                        # new neighbours: the two linear stages again (warm)
            self.phase, self._solved_phase = 1, 0
        undecided = any(p not in self._decided_for for p in self._candidates)
        if self.phase == 1:
            change = self._rotation_step(closures, anchor)
        elif self.phase == 2:
            change = self._translation_step(closures, anchor)
        else:
            change = self._refine_step(closures, anchor)
        if math.isfinite(change):
            self._solved_phase = self.phase
        elif self._solved_phase < self.phase:
            return {}                        # nothing computed in this stage yet: our values would mislead
        self.converged = change < (self.tol if self.phase == 3 else self.stage_tol)
        messages = self._separator_messages(closures)       # what this stage computed, before moving on
        if self.converged and self.phase < 3 and not undecided and all(
                self._peer_phase.get(p, (0, False))[0] > self.phase
                or self._peer_phase.get(p, (0, False)) == (self.phase, True) for p in self.neighbours()):
            self.phase += 1
            self.converged = False
        return messages

    def _ghosts(self, closures: list[Candidate], phase: int) -> dict[int, np.ndarray]:
        store = self._ghost[phase]
        return {c.peer_id: store[c.peer_id] for c in closures if c.peer_id in store}

    def _rotation_step(self, closures: list[Candidate], anchor: bool) -> float:
        ghosts = self._ghosts(closures, 1)
        graph, index = self._own_graph(ghosts, [c for c in closures if c.peer_id in ghosts])
        known = {index[v]: g for v, g in ghosts.items()}
        if anchor:
            known[0] = np.array([1.0, 0.0])
        if not known:
            return math.inf
        try:
            r = chordal_rotations(graph, known)[:len(self.ids)]
        except RuntimeError:
            return math.inf
        new = self._r + self.sor * (r - self._r)
        change = float(np.abs(new - self._r).max())
        self._r = new
        self.estimate[:, 2] = np.arctan2(new[:, 1], new[:, 0])
        return change

    def _translation_step(self, closures: list[Candidate], anchor: bool) -> float:
        ghosts_t = self._ghosts(closures, 2)
        ghosts_r = self._ghosts(closures, 1)
        usable = {v: t for v, t in ghosts_t.items() if v in ghosts_r}
        graph, index = self._own_graph(usable, [c for c in closures if c.peer_id in usable])
        theta = np.zeros(graph.n)
        theta[:len(self.ids)] = self.estimate[:, 2]
        for v in usable:
            theta[index[v]] = math.atan2(ghosts_r[v][1], ghosts_r[v][0])
        known = {index[v]: t for v, t in usable.items()}
        if anchor:
            known[0] = np.zeros(2)
        if not known:
            return math.inf
        try:
            t = chordal_translations(graph, theta, known)[:len(self.ids)]
        except RuntimeError:
            return math.inf
        new = self.estimate[:, :2] + self.sor * (t - self.estimate[:, :2])
        change = float(np.abs(new - self.estimate[:, :2]).max())
        self.estimate[:, :2] = new
        return change

    def _refine_step(self, closures: list[Candidate], anchor: bool) -> float:
        ghosts = self._ghosts(closures, 3)
        rot, trans = self._ghosts(closures, 1), self._ghosts(closures, 2)
        for v, t in trans.items():          # a neighbour still finishing phase 2: its stage-two estimate
            if v not in ghosts and v in rot:
                ghosts[v] = np.array([t[0], t[1], math.atan2(rot[v][1], rot[v][0])])
        use = [c for c in closures if c.peer_id in ghosts]
        graph, index = self._own_graph(ghosts, use)
        graph.fixed = {index[v] for v in ghosts} | ({0} if anchor or not ghosts else set())
        try:
            result = optimize(graph, initial=graph.poses, max_iterations=self.lm_iterations)
        except GraphError as exc:
            log.debug("robot %d: local refinement skipped: %s", self.robot, exc)
            return math.inf
        new = result.poses[:len(self.ids)]
        d = self.estimate - new
        d[:, 2] = wrap(d[:, 2])
        self.estimate = new
        return float(np.abs(d).max())

    def _separator_messages(self, closures: list[Candidate]) -> dict[int, Separators]:
        """Each neighbour gets the separators it shares closures with -- only those that moved more
        than ``send_tol`` since it last heard of them (event-triggered: the tail of the iteration
        costs little), and the stage's flag whenever it changes."""
        out: dict[int, Separators] = {}
        by_peer: dict[int, list[int]] = {}
        for c in closures:
            by_peer.setdefault(self._peer_owner[c.peer_id], []).append(self._index[c.own])
        for p, rows in by_peer.items():
            rows = np.array(sorted(set(rows)), np.int64)
            ids = np.array(self.ids, np.int64)[rows]
            values = (self._r if self.phase == 1 else self.estimate[:, :2] if self.phase == 2 else self.estimate)[rows]
            state, known = self._last_sent.setdefault(p, ((0, False), {}))
            told = np.array([known.get((self.phase, int(v)), np.full(values.shape[1], np.inf)) for v in ids])
            diff = np.abs(told - values)
            if self.phase == 3:
                diff[:, 2] = np.abs(wrap(told[:, 2] - values[:, 2])) if np.isfinite(told).all() else diff[:, 2]
            moved = ~(diff.max(axis=1, initial=0.0) <= self.send_tol)
            if not moved.any() and state == (self.phase, self.converged):
                continue                     # nothing new for this peer: stay quiet
            for v, value in zip(ids[moved].tolist(), values[moved]):
                known[(self.phase, v)] = value.copy()
            self._last_sent[p] = ((self.phase, self.converged), known)
            out[p] = Separators(phase=self.phase, ids=ids[moved], values=values[moved].copy(), converged=self.converged)
        return out
