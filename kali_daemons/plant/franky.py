"""An FR3 cell's plant: franky-sim, a MuJoCo FR3 that serves libfranka's network protocol
(Apache-2.0, not written here), so every byte Kali's links exchange with it is the real
robot's protocol (docs/decisions/0015).

One simulated FR3 per arm of the cell, each serving its arm's address (127.0.0.x), at its
base position and its robot type's home pose; every plant period, each robot's commands are
taken, the world steps 1 ms and each robot's state goes out.  In lockstep each FR3's link and
the plant take turns on every state (``turns.py``).  The truth (joint angles,
velocities, applied torques) goes into the plant's truth records for tests and the viewer;
``kalictl push`` pushes an FR3 at its flange.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core import layout
from ..core.errors import DaemonError
from ..runtime.daemon import Daemon
from .turns import PlantTurns

FRANKY_STEP_MS = 1.0  # franky-sim steps its world 1 ms per step, like the FR3's cycle


class FrankySim(Daemon):
    """franky-sim hosted as the cell's plant: self-timed in real time."""

    kind = "plant"
    self_timed_in_realtime = True

    def on_configure(self) -> None:
        from franky_sim import SimulationServer  # only an FR3 cell's plant loads it
        from franky_sim.mujoco_simulator import MujocoSimulator

        cfg = self.inst.config
        if self.period_ns != round(FRANKY_STEP_MS * 1e6):
            raise DaemonError(
                f"{self.name}: franky-sim steps {FRANKY_STEP_MS:g} ms; "
                "processes.plant.period_ms must be 1"
            )
        robots = [r for r in cfg.robots if r.hardware.kind == "franka"]
        if cfg.scene.objects:
            names = ", ".join(o.name for o in cfg.scene.objects)
            raise DaemonError(
                f"{self.name}: franky-sim simulates its own world, not the scene's objects "
                f"({names}, {cfg.scene.source}): give an FR3 cell an empty scene"
            )
        self.sim: Any = MujocoSimulator(enable_visualization=False)
        self.sim.init()
        self.robots = [
            self.sim.add_robot(initial_q=tuple(r.type.q_home), position=tuple(r.base_xyz))
            for r in robots
        ]
        wanted = [r.hardware.simulator_address or r.hardware.address for r in robots]
        self.server: Any = SimulationServer(self.sim, wanted)
        self.server.init()
        served = [rs.hostname for rs in self.server.robot_servers]
        if served != wanted:
            raise DaemonError(f"{self.name}: franky-sim serves {served}, the cell wants {wanted}")
        m = cfg.joints
        self._truth = self.inst.arena.record(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, m.total)
        self._world = self.inst.arena.record(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH, None)
        index = {r.name: k for k, r in enumerate(cfg.robots)}
        self._spans = [m.span(index[r.name]) for r in robots]
        self._ticks = 0
        # kalictl push: a force at each FR3's flange (its hand's origin) for a while
        self.pushes = self.inst.arena.record(layout.KEY_PUSHES, layout.PUSH, len(cfg.robots))
        self._arm_of = [index[r.name] for r in robots]
        p = self.pushes  # its fields viewed once (a lookup by name builds a view)
        self._push_fields = (p["seq"], p["duration_ns"], p["force"])
        self._push_seq = [int(p["seq"][k]) for k in self._arm_of]
        self._push_end = [0] * len(robots)
        model = self.sim.model
        self._hands = [model.body(f"robot{i}_hand").id for i in range(len(robots))]
        self.turns: PlantTurns | None = None
        if self.inst.lockstep:  # serves the links' connections from here on
            self._step([])  # a first step: franky-sim has a state
            self._ticks = 1
            self.turns = PlantTurns(self.inst, self.server.robot_servers, self._arm_of)

    def cycle(self, tick: int) -> None:
        """One 1 ms step: commands in, the world stepped, states out; the truth published.
        In lockstep, in turns with the links: a link late for its turn halts the cell."""
        turns = self.turns
        if turns is not None:
            turns.before_step(tick)
        self._push()
        self._step(self.server.robot_servers if turns is None else turns.sending)
        self._ticks += 1
        truth = self._truth
        for robot, span in zip(self.robots, self._spans, strict=True):
            inner = robot._get_state()  # franky-sim's own truth (what it packs into states)
            truth["q"][span] = inner.q
            truth["qd"][span] = inner.dq
            truth["torque"][span] = inner.tau_j
        self._world["ticks"] = self._ticks
        self._world["sim_time_ns"] = self._ticks * 1_000_000
        if turns is not None:
            turns.after_step(tick)

    def _step(self, sending: list[Any]) -> None:
        """franky-sim's ``run_once`` without its closing ``time.sleep(0)`` (a yield that cost
        ~80 µs a step here): every robot's commands in, the world stepped, the states of
        the robot servers ``sending`` out."""
        for rs in self.server.robot_servers:
            rs.process_commands()
        self.sim.step()
        for rs in sending:
            rs.send_state()

    def _push(self) -> None:
        """Start, hold or end each FR3's push (``kalictl push``; PUSH: a force in the world
        frame for a simulated duration), applied at its flange: MuJoCo applies a body's
        force at its centre of mass, so with the moment that moves it to the hand's origin."""
        data, now = self.sim.data, self._ticks * 1_000_000
        seqs, durations, forces = self._push_fields
        for i, k in enumerate(self._arm_of):
            body, xfrc = self._hands[i], data.xfrc_applied[self._hands[i]]
            seq = int(seqs[k])
            if seq != self._push_seq[i]:
                self._push_seq[i] = seq
                self._push_end[i] = now + int(durations[k])
            if now < self._push_end[i]:
                force = forces[k]
                xfrc[:3] = force
                xfrc[3:] = np.cross(data.xpos[body] - data.xipos[body], force)
            else:
                xfrc[:] = 0.0

    def on_shutdown(self) -> None:
        turns: PlantTurns | None = getattr(self, "turns", None)
        if turns is not None:
            turns.close()
        server, sim = getattr(self, "server", None), getattr(self, "sim", None)
        if server is not None:
            server.cleanup()
        if sim is not None:
            sim.cleanup()


if __name__ == "__main__":  # python -m kali_daemons.plant.franky --instance NAME --name plant
    from ..runtime.daemon import run_daemon  # run as a program only

    run_daemon(FrankySim)
