"""Privileged scripted expert for gym-pusht 0.1.8 ("push primitives with an exact model").

gym-pusht is quasi-static (damping 0, frictionless contacts) and deterministic, so a private
``PushTEnv`` replays a candidate action sequence exactly. Every replan enumerates contact points on the
T outline, builds a collision-free approach path to each (straight, or along a circle around the block's
centre of gravity), branches into push depths, simulates every candidate, and executes the one with
the best keypoint-error reduction per step (a candidate that reaches success wins outright).

Unlike a teleoperator's far-away jumps, every action sequence is *densified*: consecutive targets are at
most ``max_step`` px apart (``geometry.densify``), and the plan is simulated with exactly those targets.
This produces smooth, teleop-like demonstrations that imitation learning can fit.

The expert reads the simulator state; policies trained on its data may not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lerobot_dcdp.sim.pusht_geometry import (
    COG,
    EDGES_T,
    GOAL_POSE,
    LOCAL_KP,
    block_vertices,
    clip_offset,
    densify,
    distance_to_t,
    keypoint_error,
    keypoints,
    rot,
)

DT, KP, KV, N_SUBSTEPS = 0.01, 100.0, 20.0, 10
AGENT_RADIUS = 15.0


class ExactSim:
    """Replays ``PushTEnv.step`` physics bit for bit on a private pymunk space."""

    def __init__(self) -> None:
        from gym_pusht.envs.pusht import PushTEnv

        self.env = PushTEnv(obs_type="state")
        self.env.reset(seed=0)
        #: Block translation (px) applied before every step's physics, clipped to the arena as
        #: ``pusht_perturbed`` does: the expert's model of a constant drift. (0, 0): none.
        self.drift = np.zeros(2)

    def set_state(self, agent_pos, agent_vel, block_pose, block_vel=(0.0, 0.0), block_w=0.0) -> None:
        e = self.env
        e._setup()  # fresh space: no cached arbiters leak between candidates
        e.agent.position = (float(agent_pos[0]), float(agent_pos[1]))
        e.agent.velocity = (float(agent_vel[0]), float(agent_vel[1]))
        e.block.angle = float(block_pose[2])  # angle first, then position -> exact pose
        e.block.position = (float(block_pose[0]), float(block_pose[1]))
        e.block.velocity = (float(block_vel[0]), float(block_vel[1]))
        e.block.angular_velocity = float(block_w)

    def get_state(self) -> tuple:
        e = self.env
        return (
            tuple(e.agent.position),
            tuple(e.agent.velocity),
            np.array([e.block.position[0], e.block.position[1], e.block.angle]),
            tuple(e.block.velocity),
            float(e.block.angular_velocity),
        )

    def run(self, actions: list[np.ndarray]) -> list[np.ndarray]:
        """Block poses after each env step of ``actions``."""
        agent, space, block = self.env.agent, self.env.space, self.env.block
        drifting = bool(self.drift.any())
        poses = []
        for ax, ay in actions:
            if drifting:
                offset, _ = clip_offset(block_vertices(block.position, block.angle), self.drift)
                block.position = (block.position[0] + offset[0], block.position[1] + offset[1])
            for _ in range(N_SUBSTEPS):
                px, py = agent.position
                vx, vy = agent.velocity
                agent.velocity = (
                    vx + (KP * (ax - px) - KV * vx) * DT,
                    vy + (KP * (ay - py) - KV * vy) * DT,
                )
                space.step(DT)
            poses.append(np.array([block.position[0], block.position[1], block.angle]))
        return poses

    def coverage(self, pose: np.ndarray) -> float:
        e = self.env
        e.block.angle = float(pose[2])
        e.block.position = (float(pose[0]), float(pose[1]))
        return e._get_coverage()


#: Mean corner distance (px) below which a pose counts as reaching the goal (with coverage > 0.95).
SUCCESS_KP_ERROR = 2.8
_LOCAL_CENTROID = LOCAL_KP.mean(axis=0)
_GOAL_CENTROID = keypoints(GOAL_POSE).mean(axis=0)


def first_success(poses: list[np.ndarray], sim: ExactSim) -> int | None:
    """Index of the first pose with ``keypoint_error < 2.8`` and coverage > 0.95, or None.

    The same answer as testing every pose in turn, faster: the mean corner distance is at least the distance
    between the corners' centroids (triangle inequality), so only the poses whose centroid lies within
    2.8 px (plus a rounding margin) of the goal's are tested exactly.
    """
    if not poses:
        return None
    arr = np.asarray(poses, dtype=float)
    c, s = np.cos(arr[:, 2]), np.sin(arr[:, 2])
    cx = arr[:, 0] + c * _LOCAL_CENTROID[0] - s * _LOCAL_CENTROID[1]
    cy = arr[:, 1] + s * _LOCAL_CENTROID[0] + c * _LOCAL_CENTROID[1]
    near = np.hypot(cx - _GOAL_CENTROID[0], cy - _GOAL_CENTROID[1]) < SUCCESS_KP_ERROR + 1e-6
    for t in np.flatnonzero(near):
        if keypoint_error(poses[t]) < SUCCESS_KP_ERROR and sim.coverage(poses[t]) > 0.95:
            return int(t)
    return None


@dataclass
class ExpertConfig:
    """Knobs of the scripted expert.

    Args:
        max_step: Largest distance (px) between consecutive action targets.
        spacing: Distance (px) between candidate contact points on the T outline.
        gap: Clearance (px) between the agent and the T at the pre-contact point.
        depths: Push depths (px past the contact point) tried for every contact.
        push_steps: Steps the final push target is held.
        nav_radius: Radius (px) of the circle around the block's centre used to walk around it.
        arc_step_deg: Angular spacing of the waypoints on that circle.
        c0: Step-count offset in the score ``(err0 - err) / (steps + c0)``.
        top_k: Execute a random one of the ``top_k`` best candidates (seeded diversity); 1 = greedy.
        max_exec: Replan after at most this many executed steps (None: execute the whole primitive).
    """

    max_step: float = 20.0
    spacing: float = 6.0
    gap: float = 2.0
    depths: tuple[float, ...] = (0.5, 1.5, 3.0, 6.0, 12.0, 25.0, 50.0)
    push_steps: int = 3
    nav_radius: float = 108.0
    arc_step_deg: float = 28.0
    c0: float = 2.0
    top_k: int = 1
    max_exec: int | None = None
    contacts: list = field(default_factory=list, repr=False)


class ScriptedExpert:
    """Plans smooth push primitives on an exact simulator copy; see the module docstring."""

    def __init__(self, config: ExpertConfig | None = None, seed: int = 0) -> None:
        self.cfg = config or ExpertConfig()
        self.sim = ExactSim()
        self.rng = np.random.default_rng(seed)
        self.contacts: list[tuple[np.ndarray, np.ndarray]] = []
        for a, b, n in EDGES_T:
            a, b, n = np.array(a, float), np.array(b, float), np.array(n, float)
            k = max(int(round(np.linalg.norm(b - a) / self.cfg.spacing)), 1)
            for t in np.linspace(0, 1, k + 1):
                c = a + t * (b - a)
                if distance_to_t(c + n * (AGENT_RADIUS + self.cfg.gap)) >= AGENT_RADIUS + self.cfg.gap - 1e-6:
                    self.contacts.append((c, n))

    # ------------------------------------------------------------------ geometry
    @staticmethod
    def _to_local(p, pose):
        return rot(pose[2]).T @ (np.asarray(p) - pose[:2])

    @staticmethod
    def _to_world(p, pose):
        return rot(pose[2]) @ np.asarray(p) + pose[:2]

    def _segment_clear(self, p0, p1, pose, margin=1.0) -> bool:
        a, b = self._to_local(p0, pose), self._to_local(p1, pose)
        n = max(int(np.linalg.norm(b - a) / 4.0), 1)
        return all(distance_to_t(a + t * (b - a)) >= AGENT_RADIUS + margin for t in np.linspace(0, 1, n + 1))

    def _approach(self, agent, target, n_world, pose) -> list[np.ndarray]:
        """Waypoints from the agent to the pre-contact point ``target`` that walk around the T."""
        if self._segment_clear(agent, target, pose):
            return [target]
        cog = self._to_world(COG, pose)
        radius = self.cfg.nav_radius
        d = target - cog
        bq = float(d @ n_world)
        s = -bq + math.sqrt(max(bq * bq - (d @ d - radius * radius), 0.0))
        entry = target + n_world * max(s, 0.0)
        va = agent - cog
        ra = np.linalg.norm(va) + 1e-9
        wps = []
        if ra < radius - 5:
            wps.append(cog + va / ra * radius)
        a0 = math.atan2(va[1], va[0])
        a1 = math.atan2(entry[1] - cog[1], entry[0] - cog[0])
        da = (a1 - a0 + math.pi) % (2 * math.pi) - math.pi
        k = int(abs(da) / math.radians(self.cfg.arc_step_deg))
        for i in range(1, k + 1):
            ang = a0 + da * i / (k + 1)
            wps.append(cog + radius * np.array([math.cos(ang), math.sin(ang)]))
        wps += [entry, target]
        return [np.clip(w, 22.0, 490.0) for w in wps]

    # ------------------------------------------------------------------ planning
    def plan(
        self, prev_target, agent_pos, agent_vel, pose, block_vel=(0.0, 0.0), block_w=0.0, drift=(0.0, 0.0)
    ):
        """Best action sequence from this state, the block drifting by ``drift`` px per step meanwhile.
        Returns (score, actions)."""

        cfg, sim = self.cfg, self.sim
        sim.drift = np.asarray(drift, dtype=float)
        err0 = keypoint_error(pose)
        agent = np.asarray(agent_pos, float)
        r0 = rot(pose[2])
        candidates: list[tuple[float, list[np.ndarray]]] = []
        for c, n in self.contacts:
            nw = r0 @ n
            pre = r0 @ c + pose[:2] + nw * (AGENT_RADIUS + cfg.gap)
            if not (20 <= pre[0] <= 492 and 20 <= pre[1] <= 492):
                continue
            nav = densify(prev_target, self._approach(agent, pre, nw, pose), cfg.max_step)
            sim.set_state(agent, agent_vel, pose, block_vel, block_w)
            nav_poses = sim.run(nav)
            state = sim.get_state()
            for depth in cfg.depths:
                tgt = pre - nw * (cfg.gap + depth)
                push = densify(pre, [tgt], cfg.max_step) + [tgt] * (cfg.push_steps - 1)
                sim.set_state(*state)
                poses = nav_poses + sim.run(push)
                acts = nav + push
                succ_t = first_success(poses, sim)
                if succ_t is not None:
                    candidates.append((1e6 - succ_t, acts[: succ_t + 1]))
                else:
                    candidates.append(((err0 - keypoint_error(poses[-1])) / (len(acts) + cfg.c0), acts))
        if not candidates:
            return -1.0, []
        candidates.sort(key=lambda x: -x[0])
        if cfg.top_k > 1 and candidates[0][0] < 1e5:
            good = [c for c in candidates[: cfg.top_k] if c[0] > 0]
            if good:
                return good[int(self.rng.integers(len(good)))]
        return candidates[0]

    def next_actions(self, env, prev_target: np.ndarray) -> list[np.ndarray]:
        """Actions to execute next on a (possibly wrapped) PushT env, each within ``max_step`` of the last."""
        u = env.unwrapped
        pose = np.array([u.block.position[0], u.block.position[1], u.block.angle])
        score, acts = self.plan(
            prev_target,
            tuple(u.agent.position),
            tuple(u.agent.velocity),
            pose,
            tuple(u.block.velocity),
            u.block.angular_velocity,
        )
        if score <= 0 or not acts:  # no improving primitive: a small random step to escape
            goal = np.clip(np.asarray(u.agent.position) + self.rng.normal(0, 30, 2), 20, 492)
            acts = densify(prev_target, [goal], self.cfg.max_step)
        if self.cfg.max_exec is not None:
            acts = acts[: self.cfg.max_exec]
        return acts
