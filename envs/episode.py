"""One plan episode: the executor's stepping loop, stage by stage (``Episode``).

``envs.executor.PlanExecutor.run`` makes one ``Episode`` per plan. Each stage's waypoint is planned when
the stage starts (from the measured state), its joint targets are ramped with a minimum-jerk profile and
written to the PhysX drives only when they change, and every physics frame goes through
``env.step_physics()`` (``scene.step()`` plus the task's per-frame watch). The stages and their data are in
``prl.stages``; nothing here branches on the task.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from envs import ik
from envs.execution import EpisodeResult
from envs.hand_model import palm_anchors
from envs.reach import HandReach
from envs.scene_record import SceneParts, sapien_pose7
from envs.sensors import ContactSensors
from envs.tasks.base import pose_from_matrix
from prl.constants import N_ANCHORS, N_JOINTS, N_SENSORS
from prl.geometry import rot_x, rot_z
from prl.labels import tool_object_axis
from prl.stages import (
    FINGER,
    GRASP_POSTURES,
    JOINT_INDEX,
    MOTION_AMPLITUDES,
    MOTION_OVERSHOOT,
    PLANNING_ERRORS,
    STAGES,
    StageSpec,
)


def pose7(p: np.ndarray, r: np.ndarray) -> np.ndarray:
    return sapien_pose7(pose_from_matrix(p, r))


def _pose_matrix(pose: Any) -> np.ndarray:
    return np.asarray(pose.to_transformation_matrix(), dtype=np.float64)


def _min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector ``a`` onto unit vector ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1 + 1e-9:  # opposite: rotate pi about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def _min_jerk(s: np.ndarray | float) -> np.ndarray | float:
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s * s)


class Episode:
    """State of one plan execution; ``executor`` is the ``PlanExecutor`` that runs it (its config, env and PLB)."""

    def __init__(self, executor: Any, plan: np.ndarray) -> None:
        self.ik = ik
        self.cfg = executor.config
        self.env = executor.env
        self.plan = plan
        self.plb = executor.plb
        names = executor.plb.decode(plan)
        self.rot_x = np.deg2rad(float(names[0]))
        self.rot_z = np.deg2rad(float(names[1]))
        self.anchor = int(names[2])
        self.pattern = str(names[3])
        self.motion = str(names[4])
        self.fv_axis = str(names[5])
        self.anchor_local = palm_anchors()[self.anchor]
        agent = self.env.agent
        self.agent = agent
        self.art = agent.robot._objs[0]
        self.joints = self.art.get_active_joints()
        self.perm = agent.joint_perm
        self.palm_body = agent.palm_link._objs[0]
        self.tool_body = self.env.tool._bodies[0]
        self.sensors = ContactSensors(self.env.scene, agent.sensor_links, exclude=agent.robot)
        self.parts = SceneParts(self.env)
        """Every other body that moves (tool, debris, mechanisms), recorded each recorded frame for a replay."""
        self.spec: StageSpec = type(self.env).stages
        self.sim_freq = executor.sim_freq
        self._ahead: dict[str, np.ndarray] = {}
        """Targets planned ahead for a later stage (approach by the pregrasp, place and motion by the transport)."""
        self.notes: list[str] = []
        self.fault = ""
        self.current_target = self._qpos()
        self.root = _pose_matrix(self.art.get_root_pose())

    # ------------------------------------------------------------------ state
    def _qpos(self) -> np.ndarray:
        return np.asarray(self.art.get_qpos(), dtype=np.float64)[self.perm]

    def _qvel(self) -> np.ndarray:
        return np.asarray(self.art.get_qvel(), dtype=np.float64)[self.perm]

    def _write_targets(self, q: np.ndarray) -> None:
        for i in range(N_JOINTS):
            self.joints[self.perm[i]].set_drive_target(float(q[i]))

    def _solve(self, pos: np.ndarray, rot: np.ndarray, q_ref: np.ndarray, point: np.ndarray | None = None) -> np.ndarray:
        return self.ik.solve_palm_pose(pos, rot, q_ref, point=point, root=self.root)

    # ------------------------------------------------------------------ planning
    def _grasp_frame(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """(gv centre, palm rotation at grasp, palm normal n (world, out of the palm front), radius along n)."""
        center, half, r_gv = self.env.tool_gv_world()
        r_palm = r_gv @ rot_x(self.rot_x) @ rot_z(self.rot_z)
        out = r_palm[:, 1]  # +Y_palm: from the front face back into the hand; the handle lies along -Y_palm
        extent = float(np.sum(np.abs(r_gv.T @ out) * half))  # support of T_gv along the palm normal
        return center, r_palm, out, extent

    def plan_pregrasp(self, q_now: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        center, r_palm, out, extent = self._grasp_frame()
        posture = GRASP_POSTURES[self.pattern]
        open_q = posture.open
        ref = q_now.copy()
        ref[FINGER] = open_q
        ref[6:8] = 0.0
        far = self._solve(center + out * (extent + self.cfg.pregrasp_clearance), r_palm, ref, self.anchor_local)
        near = self._solve(center + out * (extent + posture.gap), r_palm, ref, self.anchor_local)
        return far, near

    def plan_grasp(self, q_near: np.ndarray) -> np.ndarray:
        q = q_near.copy()
        q[FINGER] = GRASP_POSTURES[self.pattern].closed
        return q

    def plan_lift(self, q_grasp: np.ndarray) -> np.ndarray:
        q = q_grasp.copy()
        q[JOINT_INDEX["ARTz"]] += self.cfg.lift_height
        return q

    def _motion_vector(self) -> np.ndarray:
        """Joint displacement of the motion: its first catalogue template times its amplitude."""
        first = int(np.argmax(self.plb.template_to_motion == self.plan[4]))
        return self.plb.template_matrix()[first] * MOTION_AMPLITUDES[self.motion] * self.spec.motion_scale

    def plan_place(self, q_target_now: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(hover, place, strike) joint targets from the measured tool-in-palm transform."""
        palm_w = _pose_matrix(self.palm_body.get_entity_pose())
        tool_w = _pose_matrix(self.tool_body.get_entity_pose())
        tool_in_palm = np.linalg.inv(palm_w) @ tool_w
        fv_center_local, fv_half = (np.asarray(x, dtype=np.float64) for x in self.env.tool_fv_local)
        obj_p, obj_r = self.env.object_frame_world()
        z_obj = obj_r[:, 2]
        u = tool_object_axis(self.fv_axis)
        r_tool = tool_w[:3, :3]
        axis_w = r_tool @ u
        target_dir = z_obj if np.dot(axis_w, z_obj) >= 0 else -z_obj
        r_new = _min_rotation(axis_w, target_dir) @ r_tool
        # the side T_fv comes from (the task's ``fv_approach``, object frame), and T_fv's leading point
        # towards the object: the box support along -approach
        approach = obj_r @ np.asarray(self.spec.fv_approach, dtype=np.float64)
        d_local = r_new.T @ (-approach)
        support = float(np.sum(np.abs(d_local) * fv_half))
        fv_center_w_new_rel = r_new @ fv_center_local
        # tool pose at contact: T_fv's leading face on the object, centred on it
        p_tool = obj_p + approach * support - fv_center_w_new_rel
        t_tool = np.eye(4)
        t_tool[:3, :3] = r_new
        t_tool[:3, 3] = p_tool
        t_palm = t_tool @ np.linalg.inv(tool_in_palm)
        motion = self._motion_vector()
        best = None
        for sign in (1.0, -1.0):
            ref = q_target_now.copy()
            # the contact configuration with the motion completed, the place one before it
            contact_ref = ref.copy()
            if self.motion in ("wrist_horizontal", "wrist_vertical"):
                contact_ref[6:8] = 0.0
                contact_ref += sign * motion * 0.5
                contact_ref[6:8] = np.clip(contact_ref[6:8], [-0.52, -0.69], [0.17, 0.48])
            try:
                q_contact = self._solve(t_palm[:3, 3], t_palm[:3, :3], contact_ref)
            except ValueError as exc:
                self.notes.append(f"place sign {sign:+.0f}: {exc}")
                continue
            q_place = q_contact - sign * motion
            if self.motion == "finger_squeeze":
                q_place = q_contact.copy()
                q_place[JOINT_INDEX["ARTz"]] += 0.03
            back = self._fv_back(q_place, tool_in_palm, fv_center_local, obj_p, obj_r @ self.spec.push)
            if best is None or back > best[0] + 1e-6:
                best = (back, q_place, q_contact, sign)
        if best is None:
            raise ValueError("no reachable place pose: " + "; ".join(self.notes))
        _, q_place, q_contact, sign = best
        q_strike = q_contact + sign * motion * MOTION_OVERSHOOT
        lower, upper = self._limits()
        q_strike = np.clip(q_strike, lower, upper)
        q_place = np.clip(q_place, lower, upper)
        q_hover = q_place.copy()
        q_hover[JOINT_INDEX["ARTz"]] += self.cfg.hover_height
        return q_hover, q_place, q_strike

    def _fv_back(self, q: np.ndarray, tool_in_palm: np.ndarray, fv_center_local: np.ndarray,
                 obj_p: np.ndarray, push: np.ndarray) -> float:
        """How far T_fv's centre lies behind the object along the motion's direction ``push`` (world) at
        joint targets q (for the hammer: its height above the nail)."""
        m = self.root @ self.ik.link_pose(q)
        t_tool = m @ tool_in_palm
        c = t_tool[:3, :3] @ fv_center_local + t_tool[:3, 3]
        return float(np.dot(obj_p - c, push))

    def _limits(self) -> tuple[np.ndarray, np.ndarray]:
        lim = np.asarray(self.art.get_qlimit(), dtype=np.float64)[self.perm]
        return lim[:, 0], lim[:, 1]

    # ------------------------------------------------------------------ loop
    def run(self, on_stage_end: Callable[[str, int], None] | None = None) -> EpisodeResult:
        cfg = self.cfg
        frames = self.spec.stage_frames(cfg.n_frames)
        bounds = np.concatenate([[0], np.cumsum(frames)])
        starts = {int(bounds[i]): i for i in range(len(STAGES)) if frames[i] > 0}  # first frame -> stage
        n = int(cfg.n_frames)
        n_rec = (n + cfg.record_every - 1) // cfg.record_every
        rec = {
            "frame": np.zeros(n_rec, np.int64), "stage": np.zeros(n_rec, np.int64),
            "qpos": np.zeros((n_rec, N_JOINTS)), "qvel": np.zeros((n_rec, N_JOINTS)), "target": np.zeros((n_rec, N_JOINTS)),
            "force": np.zeros((n_rec, N_SENSORS)), "contact_pos": np.zeros((n_rec, N_SENSORS, 3)),
            "contact_normal": np.zeros((n_rec, N_SENSORS, 3)), "palm_pose": np.zeros((n_rec, 7)),
            "tool_pose": np.zeros((n_rec, 7)), "object_pose": np.zeros((n_rec, 7)),
            "scene_pose": np.zeros((n_rec, len(self.parts.bodies), 7)),
            "scene_qpos": np.zeros((n_rec, len(self.parts.joints))),
        }
        lower, upper = self._limits()
        q_home = self._qpos()
        self.current_target = q_home.copy()
        self._write_targets(q_home)
        waypoints: dict[int, np.ndarray] = {}
        anchors_at_grasp = np.full((N_ANCHORS, 3), np.nan)
        gv_at_grasp = self.env.tool_gv_world()
        blowup = False
        reason = ""
        stage = -1
        grasp_stage = STAGES.index("grasp")
        plan_targets = np.empty((0, N_JOINTS))
        moving: np.ndarray = np.zeros(0, np.int64)
        stage_start = 0
        scene_step = self.env.step_physics
        record_every = cfg.record_every
        perf_counter = time.perf_counter
        physics_time = 0.0
        hook_time = 0.0  # time spent in on_stage_end, left out of wall_time_s
        decided = ""  # why the task says the failure is decided (ExecutorConfig.end_decided), "" while it is not
        k = 0
        t0 = time.perf_counter()
        for frame in range(n):
            if frame in starts:
                if on_stage_end is not None and stage >= 0:
                    th = perf_counter()
                    on_stage_end(STAGES[stage], frame - 1)
                    hook_time += perf_counter() - th
                if stage == grasp_stage:  # the grasp has just ended
                    anchors_at_grasp = self.ik.anchors_world(self._qpos(), root=self.root)
                    gv_at_grasp = self.env.tool_gv_world()
                ended, stage = stage, starts[frame]
                stage_start = frame
                self.env.on_stage_start(STAGES[stage])  # every task is told; a task may keep a reference
                plan_targets, moving = self._stage_trajectory(stage, frames[stage], waypoints, lower, upper)
                if cfg.end_decided and ended >= 0:
                    decided = self._failure_decided(ended, stage, frames, waypoints, lower, upper)
                    if decided:  # nothing of this stage is stepped: the last stepped frame is frame - 1
                        break
            if moving.size:
                target = plan_targets[frame - stage_start]
                for i in moving:
                    self.joints[self.perm[i]].set_drive_target(float(target[i]))
                self.current_target = target
            ts = perf_counter()
            scene_step()
            physics_time += perf_counter() - ts
            if frame % record_every == 0:
                qpos, qvel = self._qpos(), self._qvel()
                force, cpos, cnormal = self.sensors.read()
                tool7 = sapien_pose7(self.tool_body.get_entity_pose())
                lin = np.asarray(self.tool_body.get_linear_velocity(), dtype=np.float64)
                obj_p, obj_r = self.env.object_frame_world()
                # one sum: NaN or inf in any recorded array makes it non-finite (cheaper than 9 isfinite scans)
                if not math.isfinite(qpos.sum() + qvel.sum() + tool7.sum() + lin.sum() + force.sum() + cpos.sum()
                                     + cnormal.sum() + obj_p.sum() + obj_r.sum()):
                    blowup = True
                    reason = f"blowup: non-finite state at frame {frame} (not recorded)"
                    break
                if np.linalg.norm(lin) > cfg.blowup_speed:
                    blowup = True
                    reason = f"blowup: tool speed {np.linalg.norm(lin):.1f} m/s at frame {frame}"
                rec["frame"][k] = frame
                rec["stage"][k] = stage
                rec["qpos"][k] = qpos
                rec["qvel"][k] = qvel
                rec["target"][k] = self.current_target
                rec["force"][k] = force
                rec["contact_pos"][k] = cpos
                rec["contact_normal"][k] = cnormal
                rec["palm_pose"][k] = sapien_pose7(self.palm_body.get_entity_pose())
                rec["tool_pose"][k] = tool7
                rec["object_pose"][k] = pose7(obj_p, obj_r)
                rec["scene_pose"][k] = self.parts.poses()
                rec["scene_qpos"][k] = self.parts.qpos()
                k += 1
                if blowup:
                    break
        wall = time.perf_counter() - t0 - hook_time
        if on_stage_end is not None and stage >= 0 and not decided:  # (the ended stage's hook already ran)
            on_stage_end(STAGES[stage], frame)  # the last stepped frame (n - 1 unless it blew up)
        rec = {key: value[:k] for key, value in rec.items()}
        info = self.env.evaluate()
        outcome = {key: _to_python(value) for key, value in info.items()}
        outcome["blowup"] = blowup
        if blowup:
            outcome["success"] = False
            outcome["fail"] = True
            self.notes.append(reason)
            self.fault = "blowup"
        if decided:  # a failure, as in the full episode (bench/bench_decided.py); measures at the early end
            outcome["success"] = False
            outcome["decided"] = f"after {STAGES[ended]}: {decided}"
        success = bool(outcome.get("success", False)) and not blowup
        n_stepped = frame if decided else frame + 1
        return EpisodeResult(
            plan=self.plan.copy(), outcome=outcome, success=success, anchors_at_grasp=anchors_at_grasp,
            gv_at_grasp=tuple(np.asarray(x).copy() for x in gv_at_grasp), stage_frames=frames,
            wall_time_s=wall, physics_time_s=physics_time,
            fps=(n if not (blowup or decided) else n_stepped) / wall if wall > 0 else 0.0,
            notes=self.notes, fault=self.fault, scene_bodies=self.parts.bodies, scene_joints=self.parts.joints,
            frames_stepped=n_stepped, decided=outcome.get("decided", ""), **rec,
        )

    def _stage_trajectory(self, stage: int, n_frames: int, waypoints: dict[int, np.ndarray],
                          lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame targets (n_frames, 30) of a stage (min-jerk ramp from the current target to the
        stage's waypoint, planned now from the measured state) and the joints whose target moves."""
        start_q = self.current_target.copy()
        end_q = self._stage_end(stage, waypoints, start_q, lower, upper)
        waypoints[stage] = end_q
        if STAGES[stage] == "motion":
            settle = int(n_frames * self.cfg.strike_settle_frac)
            ramp = self.cfg.strike_ramp_frames if self.spec.motion_s is None else round(self.spec.motion_s * self.sim_freq)
            ramp_start, ramp_len = settle, max(1, min(ramp, n_frames - settle))
        elif STAGES[stage] == "grasp":  # per-joint closing windows of the posture
            a, b = GRASP_POSTURES[self.pattern].windows()
            ramp_start, ramp_len = a * n_frames, (b - a) * n_frames
        else:
            ramp_start, ramp_len = 0, n_frames
        s = (np.arange(n_frames)[:, None] + 1 - np.atleast_1d(ramp_start)) / np.atleast_1d(ramp_len)
        targets = start_q + (end_q - start_q) * _min_jerk(s)
        moving = np.nonzero(np.abs(end_q - start_q) > 1e-12)[0]
        return targets, moving

    def _stage_end(self, stage: int, waypoints: dict[int, np.ndarray], start_q: np.ndarray, lower: np.ndarray,
                   upper: np.ndarray, record: bool = True) -> np.ndarray:
        """The waypoint of ``stage`` starting from the targets ``start_q``, within the joint limits; ``start_q`` when
        it cannot be planned (the stage holds still). ``record``: note why and set the fault ``unreachable`` then
        (False: a look ahead, which must leave the episode as it is)."""
        try:
            end_q = self._plan_stage(stage, waypoints, start_q)
            if not np.all(np.isfinite(end_q)):
                raise ValueError(f"non-finite joint target {np.round(end_q, 4).tolist()}")
        except PLANNING_ERRORS as exc:  # unreachable: hold still, the plan then fails physically
            if record:
                self.notes.append(f"{STAGES[stage]}: {type(exc).__name__}: {exc}")
                self.fault = self.fault or "unreachable"
            end_q = start_q.copy()
        return np.clip(end_q, lower, upper)

    def _failure_decided(self, ended: int, stage: int, frames: np.ndarray, waypoints: dict[int, np.ndarray],
                         lower: np.ndarray, upper: np.ndarray) -> str:
        """The task's answer (``PRLTaskEnv.failure_decided``) at the boundary after stage ``ended``, ``stage`` having
        just been planned."""
        def path() -> np.ndarray | None:  # computed only if the task asks where the hand goes
            return self._remaining_path(stage, frames, waypoints, lower, upper)

        return self.env.failure_decided(STAGES[ended], HandReach(self.env, path, self.root))

    def _remaining_path(self, stage: int, frames: np.ndarray, waypoints: dict[int, np.ndarray], lower: np.ndarray,
                        upper: np.ndarray) -> np.ndarray | None:
        """Waypoints (n, 30) of the joint targets still to come, ``stage`` having just been planned: the measured
        joints, the current target, this stage's waypoint, then each later stage's, planned ahead as that stage
        will plan it (from the previous waypoint alone). None when a stage still to run plans from the state it
        will find (pregrasp, transport) or closes its joints on windows of its own (grasp), not on one line."""
        later = [s for s in range(stage + 1, len(STAGES)) if frames[s] > 0]
        if STAGES[stage] == "grasp" or any(STAGES[s] in ("pregrasp", "grasp", "transport") for s in later):
            return None
        path = [self._qpos(), self.current_target.copy(), waypoints[stage]]
        for s in later:
            path.append(self._stage_end(s, waypoints, path[-1], lower, upper, record=False))
        return np.stack(path)

    def _plan_stage(self, stage: int, waypoints: dict[int, np.ndarray], start_q: np.ndarray) -> np.ndarray:
        name = STAGES[stage]
        if name == "pregrasp":
            far, self._ahead["approach"] = self.plan_pregrasp(start_q)
            return far
        if name == "grasp":
            return self.plan_grasp(start_q)
        if name == "lift":
            return self.plan_lift(start_q)
        if name == "transport":
            hover, self._ahead["place"], self._ahead["motion"] = self.plan_place(start_q)
            return hover
        if name in ("approach", "place") or (name == "motion" and self.spec.runs("place")):
            if name not in self._ahead:  # the stage that plans it could not: hold still, the plan fails
                raise ValueError(f"no {name} target: the stage that plans it found none")
            return self._ahead[name]
        if name == "motion":
            # no place stage: the motion acts from where the grasp left the hand, along the template's "+" sign
            return start_q + self._motion_vector() * (1.0 + MOTION_OVERSHOOT)
        q = start_q.copy()  # post_lift
        q[JOINT_INDEX["ARTz"]] += self.spec.post_lift_height
        return q


def _to_python(value: Any) -> Any:
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    value = np.asarray(value)
    if value.size == 1:
        item = value.reshape(-1)[0].item()
        return item
    return value.tolist()
