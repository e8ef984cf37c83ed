"""The simulated cell behind the board registers: MuJoCo world, motors, I/O and DAC boards.

``PlantSim`` is the whole plant without a process around it, so tests drive it tick by tick
in-process and the plant daemon calls ``cycle`` from its loop.  One cycle: the boards apply
their registers (power switch, watchdog, brakes); the DAC codes become amplifier volts; the
grippers weld or let go and the belt carries the bar; the motor model sets each current loop
and MuJoCo runs ``substeps`` steps; then the encoders count, the pot ADCs convert and the truth
records are written (in full: docs/internals/robots-hardware-plant.md).

Every per-joint array here (``q``, ``volts``, ``motor_angle``, ...) and the truth record
``JOINT_TRUTH`` hold the cell's joints flat, arm ``k``'s joint ``j`` at ``base[k] + j``
(``joints.JointMap``); the boards keep joint ``j`` on channel ``j`` of its arm's boards.
"""

from __future__ import annotations

import math
import zlib

import mujoco
import numpy as np

from ..core import layout
from ..core.arena import Arena
from ..core.joints import ArmCopy
from ..core.kernels import Kernel, channel_offsets, copies
from ..hardware.mcgill import registers
from ..robots.model import World, build_world
from ..runtime.config import KaliConfig
from .board import BOARD_STATE, RETRIGGER_NS, EncoderBank, FtBank, IoBoardSim, boards_kernel
from .motor import Drive, MotorBank

DAC_MAX = (1 << registers.DAC_BITS) - 1
GRASP_REACH_M = 0.03  # a closing gripper welds to the object only this close to its grasp site
BELT_LIFT_M = 0.005  # the belt carries the bar only while it lies on it (not lifted by this)
WELD_ROWS = 6  # a weld's constraint rows: force, then torque


class PlantSim:
    """The plant of one instance: owns the MuJoCo model and data, the register records and
    the truth records (``ARM_TRUTH`` per arm, ``JOINT_TRUTH`` per joint)."""

    def __init__(self, cfg: KaliConfig, arena: Arena, period_ms: float | None = None) -> None:
        """Build the world and lay out or attach the records (outside the cycle)."""
        pc = self._plant_cfg = cfg.plant
        self.dt = pc.substep_ms / 1000.0
        self.dt_ns = round(pc.substep_ms * 1e6)
        period = cfg.process("plant").period_ms if period_ms is None else period_ms
        self.substeps = max(1, round(period / pc.substep_ms))
        self.world: World = build_world(cfg.robots, timestep=self.dt, scene=cfg.scene)
        self.names = [r.name for r in cfg.robots]
        joints = self.joints = cfg.joints
        m = self.model = self.world.model
        d = self.data = mujoco.MjData(m)
        n_arms = len(self.names)
        self.dofs = np.concatenate([self.world.dof_adr[k] for k in range(n_arms)])
        self.qpos_idx = np.concatenate([self.world.qpos_adr[k] for k in range(n_arms)])
        types = [r.type for r in cfg.robots]
        self.motors = MotorBank(types)
        assert self.motors.n == joints.total, "the motors are the config's joints"
        self.acts = np.concatenate([self.world.motor[k] for k in range(n_arms)])
        self.act_adr = np.concatenate([self.world.motor_act_adr[k] for k in range(n_arms)])
        self.current = np.zeros(self.motors.n)
        m.dof_damping[self.dofs] = self.motors.damping
        # Stiff friction constraints: MuJoCo's defaults let an engaged brake creep ~8 mrad/s
        # under gravity; a 4-step time constant and impedance 0.9999 hold to < 1 µrad/s.
        m.dof_solref[self.dofs] = [4 * self.dt, 1.0]
        m.dof_solimp[self.dofs, :2] = 0.9999
        self.braked = np.ones(self.motors.n, dtype=bool)  # brakes hold at power-on
        self._frictionloss = np.zeros(self.motors.n)
        self._apply_brakes()
        d.qpos[self.qpos_idx] = np.concatenate([t.q_home for t in types])  # at power-on
        mujoco.mj_forward(m, d)
        self.gear = self.motors.gear
        self.q = np.zeros(self.motors.n)
        self.qd = np.zeros(self.motors.n)
        self.motor_angle = np.zeros(self.motors.n)
        self.volts = np.zeros(self.motors.n)
        self.torque = np.zeros(self.motors.n)
        drive = Drive(
            self.acts, self.act_adr, self.dofs, m.actuator_actrange, d.ctrl, d.act, d.qfrc_applied
        )
        self._drive = self.motors.compiled(self.volts, self.qd, self.current, drive)
        self._read_joints()
        self.regs = arena.record(registers.KEY_BOARDS, registers.IO_BOARD, n_arms)
        self.dac = arena.record(registers.KEY_DACS, registers.DAC_BOARD, n_arms)
        self.dac["code"] = registers.DAC_ZERO
        self.truth = arena.record(layout.KEY_TRUTHS, layout.ARM_TRUTH, n_arms)
        self.joint_truth = arena.record(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, joints.total)
        self._board_state = np.zeros((n_arms, BOARD_STATE), np.int64)  # the boards' rows
        self._retriggered = self._board_state[:, RETRIGGER_NS]  # when each watchdog last was
        self.boards = [
            IoBoardSim(self.regs[k : k + 1].reshape(()), pc, types[k], self._board_state[k])
            for k in range(n_arms)
        ]
        self._boards = boards_kernel(  # every board's update (its convert, truth: siblings)
            self.boards, self.regs, self.truth, joints, self.q, self.motors.enabled, self.braked
        )
        self._boards_args = self._boards.args
        self._convert = self._boards.sibling("kali_boards_convert")
        self._boards_truth = self._boards.sibling("kali_boards_truth")
        # each arm is built to its calibration sheet (thesis 3.5.1): the robot's config says it
        phases = np.concatenate([r.index_phases for r in cfg.robots])
        self.encoders = EncoderBank(self.regs, types, phases, self.motor_angle, joints)
        self._count = self.encoders.compiled(self.motor_angle)
        self._codes_to_volts = ArmCopy(joints, self.volts, self.dac["code"])
        self._spans = [joints.span(k) for k in range(n_arms)]  # each arm's joints, flat
        self._joints_in = self._io_kernel()  # _read_joints compiled; _read_dac a sibling
        self._dac_in = self._joints_in.sibling("kali_plant_dac")
        self._gripper_prev = [0] * n_arms
        self.world_truth = arena.record(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
        # the wrist sensors: MuJoCo's force and torque at each arm's sensor site,
        # through its board's gauge ADC bank; pushes on the tools from kalictl push
        self._ft_true = np.zeros((n_arms, 6))
        self._ft_src = [
            None if a < 0 else self.data.sensordata[a : a + 6] for a in self.world.ft_adr
        ]
        self.ft = [
            None
            if r.ft.sheet is None
            else FtBank(
                self.regs[k : k + 1].reshape(()),
                r.ft.sheet,
                # per robot, not per instance: the same program gives the same readings
                # under any instance name (lockstep is bit for bit)
                seed=zlib.crc32(f"ft/{r.name}".encode()),
                dt_s=self.substeps * self.dt,
            )
            for k, r in enumerate(cfg.robots)
        ]
        # each sensor's bank compiled, on its arm's true wrench (FtBank.cycle its reference)
        self._ft_steps = [
            bank.compiled(self._ft_true[k]) for k, bank in enumerate(self.ft) if bank is not None
        ]
        self._ft_arms = [k for k, src in enumerate(self._ft_src) if src is not None]
        self.pushes = arena.record(layout.KEY_PUSHES, layout.PUSH, n_arms)
        p = self.pushes  # its fields viewed once (a lookup by name builds a view)
        self._push_fields = (p["seq"], p["duration_ns"], p["force"])
        self._push_seq = [int(s) for s in p["seq"]]
        self._push_end = [0] * n_arms
        self._push_on = [False] * n_arms
        self._xfrc = [self.data.xfrc_applied[b] for b in self.world.tool_body]
        # each grasp's weld force and torque (world frame), whether it holds and what
        # (_weld_forces): the cell's only equality constraints are the welds, arm by arm, one
        # per graspable object (build_world)
        welds = [eq for arm in self.world.weld for eq in arm]
        assert welds == list(range(m.neq)), "the welds, arm by arm, are the equalities"
        assert all(int(t) == mujoco.mjtEq.mjEQ_WELD for t in m.eq_type), "welds only"
        self._eq_active = self.data.eq_active  # a view of MjData's fixed-size array
        self._held = np.zeros(n_arms, dtype=bool)
        self._held_object = np.full(n_arms, -1, dtype=np.int64)
        self._grasp_site = np.zeros(n_arms, dtype=np.int64)  # where each took hold
        self._weld = np.zeros((n_arms, WELD_ROWS))
        # the conveyor belt: it drives its object's x, y from where it was when it started
        vx, vy = cfg.plant.conveyor_m_s
        self._belt_v = (vx, vy) if (vx or vy) else None
        self._belt_from: tuple[float, float] | None = None  # the object's x, y at its start
        self._belt_cycles = 0
        if self._belt_v is not None:
            assert cfg.scene.belt is not None, "a belt carries an object (config)"
            self._belt = self.world.object_index(cfg.scene.belt)
            adr, dof = self.world.object_qpos_adr[self._belt], self.world.object_dof_adr[self._belt]
            self._belt_q = self.data.qpos[adr : adr + 3]
            self._belt_qd = self.data.qvel[dof : dof + 6]
            self._belt_rest_z = float(self._belt_q[2])
            w = self.world
            g = w.graspable.index(self._belt) if self._belt in w.graspable else None
            self._belt_welds = [] if g is None else [arm[g] for arm in w.weld]
        self.object_truth = arena.record(
            layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, len(self.world.objects)
        )
        self._period_s = self.substeps * self.dt
        self._belt_bit = self.regs["conveyor"][0:1]  # the first board's belt motor line
        self._truth_views()
        self.sim_ns = 0
        self.ticks = 0
        self._write_truth()
        self.regs["present"] = 1  # last: every register above is valid

    def place_arm(self, k: int, q: np.ndarray) -> None:
        """Put arm ``k`` at joint angles ``q`` at rest, as if moved there before power-on.

        Outside the cycle (tests and set-up).  Its encoder counters restart from 0.
        """
        self.data.qpos[self.world.qpos_adr[k]] = q
        self.data.qvel[self.world.dof_adr[k]] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self._read_joints()
        self.encoders.power_on(k, self.motor_angle[self._spans[k]])
        self._write_truth()

    # ------------------------------------------------------------------ one cycle

    def hold_watchdogs(self) -> None:
        """Let the next cycle not count for the boards' watchdogs: the machine held SIO's CPU
        (``stalls.MachineStalls``), so their timers resume where they froze.  In the cycle."""
        self._retriggered += self.substeps * self.dt_ns

    def cycle(self) -> None:
        """Advance the plant one period; inside the cycle (no allocation beyond numpy views)."""
        self._boards_args.now_ns = self.sim_ns
        changed = self._boards()  # IoBoardSim.update of each, the motors' enable, the brakes
        for k in range(len(self.boards)):
            self._gripper(k)
        if self._belt_v is not None:
            self._conveyor()
        self._dac_in()  # the DAC codes to volts (_read_dac, compiled)
        if changed:
            self._apply_brakes()
        self._push()
        self._drive()  # motors.cycle and MuJoCo's inputs from it (motor.drive_reference)
        mujoco.mj_step(self.model, self.data, self.substeps)
        self.sim_ns += self.substeps * self.dt_ns
        self._joints_in()  # angles, velocities, currents (_read_joints, compiled)
        self._count()  # the encoders (EncoderBank.sample, compiled)
        self._convert()  # the pot ADCs (IoBoardSim.convert of each, compiled)
        self._read_ft()
        self.ticks += 1
        self._write_truth()

    def _io_kernel(self) -> Kernel:
        """``_read_joints`` compiled (``csrc/plant.c``'s ``kali_plant_joints``), on a block
        ``kali_plant_dac`` (``_read_dac`` compiled) shares: MuJoCo's arrays, the DAC boards'
        records and the plant's arrays, none of which ever moves.  Outside the cycle."""
        j, d, codes = self.joints, self.data, self.dac["code"]
        robot_of = np.ascontiguousarray(j.robot_of, dtype=np.int64)
        joint_of = np.ascontiguousarray(j.joint_of, dtype=np.int64)
        arrays = {
            "qpos": d.qpos, "qvel": d.qvel, "act": d.act,
            "qpos_idx": np.ascontiguousarray(self.qpos_idx, dtype=np.int64),
            "dofs": np.ascontiguousarray(self.dofs, dtype=np.int64),
            "act_adr": np.ascontiguousarray(self.act_adr, dtype=np.int64),
            "gear": self.gear, "gkt": self.motors.gkt, "q": self.q, "qd": self.qd,
            "current": self.current, "motor_angle": self.motor_angle, "torque": self.torque,
            "dac_off": channel_offsets(codes, robot_of, joint_of), "robot_of": robot_of,
            "volts": self.volts,
        }  # fmt: skip
        for name, a in arrays.items():
            assert a.flags.c_contiguous and a.dtype in (np.float64, np.int64), f"plant: {name}"
        return Kernel(
            "kali_plant_joints",
            (self.dac, *arrays.values()),
            n=j.total,
            dacs=codes.ctypes.data,
            clamped=self.dac["clamped"],
            top=float(DAC_MAX),
            zero=float(registers.DAC_ZERO),
            scale=10.0 / registers.DAC_ZERO,
            **{name: a.ctypes.data for name, a in arrays.items()},
        )

    def _read_joints(self) -> None:
        """Angles, velocities and motor currents from MuJoCo; motor angles, joint torques
        (the reference of ``kali_plant_joints``)."""
        self.data.qpos.take(self.qpos_idx, out=self.q)
        self.data.qvel.take(self.dofs, out=self.qd)
        self.data.act.take(self.act_adr, out=self.current)
        np.multiply(self.gear, self.q, out=self.motor_angle)
        np.multiply(self.motors.gkt, self.current, out=self.torque)

    def _read_ft(self) -> None:
        """Each wrist sensor's true wrench, then its board's gauge bank.  MuJoCo gives the
        force and torque the flange applies to the tool (site frame); the sensor reads the
        tool's on the flange, the opposite."""
        for k in self._ft_arms:
            # _ft_arms lists the arms whose source is there
            np.negative(self._ft_src[k], out=self._ft_true[k])  # type: ignore[arg-type]
        for step in self._ft_steps:
            step()  # FtBank.cycle, compiled

    def _push(self) -> None:
        """Start, hold or end each arm's push on its tool (``kalictl push``): a new ``seq``
        in its PUSH record starts one for its ``duration_ns`` of simulated time."""
        seqs, durations, forces = self._push_fields
        for k, xfrc in enumerate(self._xfrc):
            seq = int(seqs[k])
            if seq != self._push_seq[k]:
                self._push_seq[k] = seq
                self._push_end[k] = self.sim_ns + int(durations[k])
                xfrc[:3] = forces[k]
                xfrc[3:] = 0.0
                self._push_on[k] = True
            elif self._push_on[k] and self.sim_ns >= self._push_end[k]:
                xfrc[:] = 0.0
                self._push_on[k] = False

    def _read_dac(self) -> None:
        """DAC codes (arm k's joint j on channel j) → amplifier input volts, flat; codes
        above 12 bits are clamped and counted on their board (the reference of
        ``kali_plant_dac``)."""
        out = self.volts
        self._codes_to_volts.to_flat()
        if out.max() > DAC_MAX:  # rare: a bad register value
            for k in self.joints.robot_of[np.flatnonzero(out > DAC_MAX)]:
                self.dac["clamped"][k] += 1
            np.minimum(out, DAC_MAX, out=out)
        np.subtract(out, registers.DAC_ZERO, out=out)
        np.multiply(out, 10.0 / registers.DAC_ZERO, out=out)

    def _apply_brakes(self) -> None:
        self.motors.joint_frictionloss(self.braked, self._frictionloss)
        self.model.dof_frictionloss[self.dofs] = self._frictionloss

    # ------------------------------------------------------------------ grasping

    def _gripper(self, k: int) -> None:
        """A rising gripper bit welds the flange to the object whose grasp is nearest, if it
        is within reach; falling lets go."""
        regs = self.boards[k].regs
        g = int(regs["gripper"])
        if g > 1:
            regs["clamped"] += 1
            g = 1
        if g == self._gripper_prev[k]:
            return
        self._gripper_prev[k] = g
        if not g:
            self.world.release(self.data, k)
            return
        i, distance = self.nearest_grasp(k)
        if distance <= GRASP_REACH_M:
            self._grasp_site[k] = self.world.grasp_site[i]
            self.world.activate_weld(self.data, k, self.world.grasp_object[i])

    def _conveyor(self) -> None:
        """Carry the scene's belt object: while the first board runs the belt's motor and the
        object lies on it (held by no gripper, not lifted), its x, y go at the belt's velocity
        from where they were when the belt started, exactly (set before each step, with that
        velocity: the stand's friction does not drag it back).  Floats only."""
        if not self._belt_bit[0]:  # the belt's motor off: the usual case, one load
            self._belt_from = None
            return
        held = any(self._eq_active[eq] for eq in self._belt_welds)
        lifted = float(self._belt_q[2]) > self._belt_rest_z + BELT_LIFT_M
        if held or lifted:  # not on the belt
            self._belt_from = None
            return
        if self._belt_from is None:
            self._belt_from = (float(self._belt_q[0]), float(self._belt_q[1]))
            self._belt_cycles = 0
        vx, vy = self._belt_v  # type: ignore[misc]
        t = self._belt_cycles * self._period_s
        self._belt_q[0] = self._belt_from[0] + vx * t
        self._belt_q[1] = self._belt_from[1] + vy * t
        self._belt_qd[0], self._belt_qd[1] = vx, vy
        self._belt_qd[3:] = 0.0
        self._belt_cycles += 1

    def nearest_grasp(self, k: int) -> tuple[int, float]:
        """The grasp nearest arm ``k``'s flange (its index in ``world.grasp_site``) and its
        distance (m); (-1, inf) in a world with nothing to hold."""
        d = self.data
        flange = d.site_xpos[self.world.flange_site[k]]
        best, distance = -1, math.inf
        for i, site in enumerate(self.world.grasp_site):
            far = float(np.linalg.norm(flange - d.site_xpos[site]))
            if far < distance:
                best, distance = i, far
        return best, distance

    def _weld_forces(self) -> None:
        """Each arm's weld force and torque (world frame) into ``_weld[k]``, whether it grasps
        into ``_held[k]`` and what into ``_held_object[k]``.  MuJoCo lays the active equality
        constraints' rows out first, ``ne`` of them, in the equalities' order, six per weld;
        the welds are the cell's only equalities, arm by arm (asserted at build), and an arm
        holds one object at most, so arm ``k``'s rows follow those of the arms before it that
        hold: counted, not searched by type and id, which would be the plant's largest cost
        while it carries an object."""
        d = self.data
        force = d.efc_force
        row = 0
        for k, welds in enumerate(self.world.weld):
            self._held[k] = False
            self._held_object[k] = -1
            for g, eq in enumerate(welds):
                if self._eq_active[eq]:
                    self._held[k] = True
                    self._held_object[k] = self.world.graspable[g]
                    self._weld[k] = force[row : row + WELD_ROWS]
                    row += WELD_ROWS
        assert row == d.ne, "the equality rows are the welds' (build_world)"

    # ------------------------------------------------------------------ truth

    def _truth_views(self) -> None:
        """View every truth field once (a field lookup by name builds a new view each time)."""
        n = len(self.boards)
        sources = (self.q, self.qd, self.current, self.torque, self.motor_angle)
        fields = ("q", "qd", "current", "torque", "motor_angle")
        self._truth_copies = copies(  # one kernel, in the simulator's library
            [(src, self.joint_truth[f]) for f, src in zip(fields, sources, strict=True)],
            "simulator",
        )
        self._truth_grasped = [self.truth[k : k + 1]["grasped"].reshape(()) for k in range(n)]
        self._truth_wrench = [self.truth["grasp_wrench"][k] for k in range(n)]
        self._truth_ft = (self.truth["ft_wrench"], self._ft_true)
        self._truth_push = [(self.truth["push"][k], x[:3]) for k, x in enumerate(self._xfrc)]
        self._truth_holding = [self.truth[k : k + 1]["held"].reshape(()) for k in range(n)]
        w = self.world_truth
        self._world_views = (w["sim_time_ns"], w["ticks"], w["internal_force"])
        m = len(self.world.objects)  # their qpos lead MuJoCo's (build_world)
        self._object_pose = (self.object_truth["pose"], self.data.qpos[: 7 * m].reshape(m, 7))
        # the rest of the truth in one kernel (_write_truth_reference is what it equals), on
        # MuJoCo's fixed-size arrays (MjData allocates them once) and the records
        d, world = self.data, self.world
        assert self._weld.shape[1] == self._ft_true.shape[1] == layout.WRENCH  # the C's WRENCH
        fixed = {
            "eq_active": d.eq_active,
            "graspable": np.array(world.graspable, dtype=np.int64),
            "held": self._held,
            "held_object": self._held_object,
            "weld": self._weld,
            "ft_true": self._ft_true,
            "xfrc": d.xfrc_applied,
            "site_xpos": d.site_xpos,
            "object_qpos": self._object_pose[1],
            "sim_time_ns": w["sim_time_ns"],
            "ticks": w["ticks"],
            "object_pose": self._object_pose[0],
            "internal_force": w["internal_force"],
            "tool_body": np.array(world.tool_body, dtype=np.int64),
            "grasp_site": self._grasp_site,
        }
        for name, a in fixed.items():
            assert a.flags.c_contiguous, f"plant: {name} must be contiguous for its kernel"
        t = self.truth
        self._truth = Kernel(
            "kali_plant_truth",
            (t, w, d, self.object_truth, *fixed.values()),
            n=n,
            welds=len(world.graspable),
            objects=m,
            grasped=t["grasped"],
            holding=t["held"],
            grasp_wrench=t["grasp_wrench"][:, 0],
            ft_wrench=t["ft_wrench"][:, 0],
            push=t["push"][:, 0],
            **{name: a.ctypes.data for name, a in fixed.items()},
        )
        self._truth_args = self._truth.args

    def _write_truth(self) -> None:
        """The plant-only records (outside the controller's view): true state of every joint
        and arm, in three kernels (``_write_truth_reference`` is what they equal)."""
        self._truth_copies()
        self._boards_truth()  # amplifiers, brakes, watchdog, e-stop
        args = self._truth_args
        args.sim_ns, args.cycles = self.sim_ns, self.ticks
        if self._truth():  # a weld holds: its rows from MuJoCo's constraint forces first
            self._weld_forces()
            args.welds_read = 1
            self._truth()

    def _write_truth_reference(self) -> None:
        """``_write_truth`` in Python and numpy, step for step (its kernel's reference)."""
        self._truth_copies()
        self._weld_forces()
        self._boards_truth()  # amplifiers, brakes, watchdog, e-stop
        for k in range(len(self.boards)):
            held = bool(self._held[k])
            wrench = self._truth_wrench[k]
            if held:
                np.copyto(wrench, self._weld[k])
            else:
                wrench[:] = 0.0
            self._truth_grasped[k][...] = held
            self._truth_holding[k][...] = self._held_object[k]
        np.copyto(*self._truth_ft)
        for dst, src in self._truth_push:
            np.copyto(dst, src)
        t_ns, ticks, internal = self._world_views
        t_ns[...] = self.sim_ns
        ticks[...] = self.ticks
        internal[...] = self._internal_force()
        np.copyto(*self._object_pose)

    def _internal_force(self) -> float:
        """Squeeze (+) or tension (−) along the line between the first two grasps of one
        object, N (each weld's force is the object's on the tool); 0 unless two hold it."""
        a = b = -1
        for k, held in enumerate(self._held):
            if held and a < 0:
                a = k
            elif held and self._held_object[k] == self._held_object[a]:
                b = k
                break
        if b < 0:
            return 0.0
        xpos = self.data.site_xpos  # in scalars: the order of every operation is the kernel's
        pa, pb = xpos[self._grasp_site[a]], xpos[self._grasp_site[b]]
        u0, u1, u2 = (float(pb[c] - pa[c]) for c in range(3))
        norm = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        if norm == 0.0:
            return 0.0
        u0, u1, u2 = u0 / norm, u1 / norm, u2 / norm
        fa0, fa1, fa2 = (float(f) for f in self._weld[a, :3])
        fb0, fb1, fb2 = (float(f) for f in self._weld[b, :3])
        return 0.5 * ((fb0 * u0 + fb1 * u1 + fb2 * u2) - (fa0 * u0 + fa1 * u1 + fa2 * u2))
