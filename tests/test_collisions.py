"""Collisions, simulated (issue 56 item 2): in the plant every arm's links collide with the
other arms' and with the world, from the URDFs' collision shapes, so a crash is a crash: the
arms stop against each other and SIO's checks halt the cell naming an arm; the flight
recorder's dump holds the fault.  Known to the controller (item 3): the same shapes in coal,
the TG's check refusing a motion that would come within the scene's clearance."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np
import pytest

from kali_daemons.client import Kali, pose
from kali_daemons.client.common import MotionFailedError
from kali_daemons.core.errors import MotionError, ServoError
from kali_daemons.core.layout import RequestState
from kali_daemons.robots import model
from kali_daemons.robots.scene import DEFAULT_SCENE, parse_scene
from kali_daemons.wallclock import step_kali_clock
from tests.conftest import make_config
from tests.test_launcher import kalictl

DOWN = np.diag([1.0, -1.0, -1.0])  # the flange's z straight down
UNCHECKED = "KALI_TEST_UNCHECKED_CLEARANCE"  # the TG's test-only switch: no clearance check


WALLED = """version: 1
objects:
  - {name: wall, shape: box, size: [0.05, 0.6, 0.6], at: [-0.3, 0.3, 0.3], fixed: true}
  - {name: screen, shape: box, size: [0.05, 0.6, 0.6], at: [0.3, 0.3, 0.3], fixed: true,
     arms_touch: false}
  - {name: block, shape: box, size: [0.04, 0.04, 0.04], at: [0, 0.5, 0.02], mass: 0.2}
"""


def test_arm_links_collide_with_other_arms_and_the_world_not_their_own() -> None:
    """The contact bits: an arm's collision shapes touch the other arms', the floor, the
    fixtures and free objects of the scene (unless ``arms_touch: false``), never the same
    arm's; its visual shapes touch nothing; the shipped scene's stand, table and bar are
    passed through (``arms_touch: false``) and still carry the bar."""
    cfg = make_config("collision-bits")
    geom = mujoco.mjtObj.mjOBJ_GEOM

    def collide(m: mujoco.MjModel, a: int, b: int) -> bool:
        ab = m.geom_contype[a] & m.geom_conaffinity[b]
        return bool(ab or m.geom_contype[b] & m.geom_conaffinity[a])

    def shapes(m: mujoco.MjModel, robot: str) -> list[int]:
        return [
            g
            for g in range(m.ngeom)
            if m.geom_group[g] == 3 and m.body(m.geom_bodyid[g]).name.startswith(f"{robot}/")
        ]

    m = model.build_world(cfg.robots, scene=parse_scene(WALLED, "walled.yaml")).model
    left, right = shapes(m, "left"), shapes(m, "right")
    assert left and right
    touched = [mujoco.mj_name2id(m, geom, n) for n in ("wall", "floor", "block")]
    screen = mujoco.mj_name2id(m, geom, "screen")
    visuals = [g for g in range(m.ngeom) if m.geom_group[g] == 1]
    for a in left:
        assert all(collide(m, a, b) for b in right)
        assert not any(collide(m, a, b) for b in left)
        assert all(collide(m, a, g) for g in touched) and not collide(m, a, screen)
    assert not any(m.geom_contype[g] or m.geom_conaffinity[g] for g in visuals)
    block = mujoco.mj_name2id(m, geom, "block")
    assert collide(m, block, screen) and collide(m, block, touched[0])  # it rests on both
    shipped = model.build_world(cfg.robots, scene=cfg.scene).model
    world = [mujoco.mj_name2id(shipped, geom, n) for n in ("stand", "table", "bar")]
    assert not any(collide(shipped, a, g) for a in shapes(shipped, "left") for g in world)
    bar, stand = world[2], world[0]
    assert collide(shipped, bar, stand)


def test_two_arms_driven_into_each_other_crash_and_halt_naming_an_arm(
    kali: Callable[..., str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Lockstep: both arms sent to flange poses 4 cm apart above the stand, the TG's
    clearance check off (the test-only switch: it would refuse both moves): their wrists meet
    on the way, the flanges never come closer than the arms' bodies let them, and the cell
    halts with a fault naming an arm; ``kalictl flight`` shows the dump of that fault."""
    monkeypatch.setenv(UNCHECKED, "1")
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready(["left", "right"])
        arms = [k.robot("left"), k.robot("right")]
        turned = DOWN @ np.diag([-1.0, -1.0, 1.0])  # the right arm's flange x the other way
        targets = [pose([-0.02, 0.0, 0.78], DOWN), pose([0.02, 0.0, 0.78], turned)]
        handles = [
            arm.move_joints(arm.joints_at(t, "run"), speed=0.3, wait=False)
            for arm, t in zip(arms, targets, strict=True)
        ]
        closest = np.inf
        for _ in range(4000):
            step_kali_clock(k.inst, 1)
            flanges = [k.sim.truth(a.name).flange[:3, 3] for a in arms]
            closest = min(closest, float(np.linalg.norm(flanges[0] - flanges[1])))
            if all(h.done for h in handles):
                break
        fault = k.inst.fault_text(last=True)
        assert fault is not None, f"no halt; the flanges came {closest:.3f} m apart"
        assert "robot 'left'" in fault or "robot 'right'" in fault, fault
        assert any(h.state == RequestState.HALTED for h in handles)
        assert closest > 0.06, f"the flanges came {closest:.3f} m apart: the arms passed through"
        out = kalictl("-i", name, "flight")
        assert out.returncode == 0, out.stderr
        assert fault.split(":")[0] in out.stdout, (fault, out.stdout)


def _mujoco_distance(m: mujoco.MjModel, d: mujoco.MjData, a: str, b: str) -> float:
    """The nearest distance between the plant's collision shapes of bodies ``a`` and ``b``
    (an arm's group-3 shapes, or a scene object's geom), as MuJoCo computes it."""

    def geoms(body: str) -> list[int]:
        found = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, body)
        if found >= 0:
            return [found]
        return [
            g
            for g in range(m.ngeom)
            if m.geom_group[g] == 3 and m.body(m.geom_bodyid[g]).name.startswith(f"{body}/")
        ]

    return min(mujoco.mj_geomDistance(m, d, x, y, 2.0, None) for x in geoms(a) for y in geoms(b))


def test_the_controllers_collision_model_measures_what_the_plant_simulates() -> None:
    """``CellGeometry.distance`` (Pinocchio's collision shapes from the URDFs, coal) against
    MuJoCo's distance between the plant's shapes of the same bodies: two arms at random joint
    angles near home, and each arm against the scene's objects, equal within 0.1 mm."""
    from kali_daemons.robots.collision import CellGeometry

    cfg = make_config("collision-model")
    scene = parse_scene(WALLED, "walled.yaml")
    world = model.build_world(cfg.robots, scene=scene)
    m = world.model
    d = mujoco.MjData(m)
    geometry = CellGeometry(cfg.robots, scene)
    rng = np.random.default_rng(56)
    home = np.array(cfg.robots[0].type.q_home)
    for _ in range(25):
        qs = [home + rng.uniform(-0.6, 0.6, 6) for _ in cfg.robots]
        for k, q in enumerate(qs):
            d.qpos[world.qpos_adr[k]] = q
        mujoco.mj_forward(m, d)
        for a, b in (("left", "right"), ("left", "wall"), ("right", "screen")):
            got = geometry.distance(a, b, qs)
            want = _mujoco_distance(m, d, a, b)
            assert got.distance == pytest.approx(want, abs=1e-4), (a, b, got, want)
            assert np.linalg.norm(got.point_a - got.point_b) == pytest.approx(
                abs(got.distance), abs=1e-6
            )


def test_a_program_asks_the_distance_between_two_bodies(kali: Callable[..., str]) -> None:
    """``kali.distance`` at the arms' measured joints: the two arms at home, an arm and the
    table, one link and the other arm; a body the cell does not have is refused naming the
    bodies it has.  As the plant's truth has it, within the encoders' resolution."""
    from kali_daemons.robots.collision import CellGeometry

    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready(["left", "right"])
        step_kali_clock(k.inst, 300)
        apart = k.distance("left", "right")
        assert apart.near_a.startswith("left/") and apart.near_b.startswith("right/")
        truth = [k.sim.truth(n).q for n in ("left", "right")]
        exact = CellGeometry(k.inst.config.robots, k.scene).distance("left", "right", truth)
        assert apart.distance == pytest.approx(exact.distance, abs=1e-4)
        assert 0.05 < apart.distance < 0.3  # the wrists face each other over the stand
        table = k.distance("left", "table")
        assert table.near_b == "table" and table.distance > 0.0
        link = k.distance("left/link6", "right")
        assert link.near_a == "left/link6" and link.distance >= apart.distance
        with pytest.raises(MotionError, match=r"no body 'anvil'.*'left', 'right', 'stand'"):
            k.distance("left", "anvil")
        with pytest.raises(MotionError, match=r"one body"):
            k.distance("left/link2", "left")


def test_moves_that_would_meet_the_other_arm_are_refused_naming_both_links(
    kali: Callable[..., str],
) -> None:
    """Lockstep, the shipped cell: the left arm's waist turned towards the right arm, and its
    flange sent in a line over to the right arm's wrist, are each refused before anything
    moves, naming a link of each arm, the distance and where on the way; the same moves
    away from it run."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready(["left", "right"])
        left = k.robot("left")
        start = k.servo.level.joints["demand"][left.span].copy()
        turn = np.radians([30, 0, 0, 0, 0, 0])
        with pytest.raises(MotionFailedError) as refused:
            left.move_joints(start + turn, speed=0.3)
        assert_refused(
            str(refused.value),
            r"joint move refused: \d+ % of the way, robot 'left' at \(.*\)°: 'left/link\d' "
            r"would (come within \d+\.\d mm of|overlap) 'right/link\d'.* \(clearance 10 mm\) at "
            r"\(.*\) m",
        )
        here = left.read_pose(demand=True)
        toward = pose(here[:3, 3] + np.array([0.0, 0.25, 0.0]), here)  # the right arm's side
        with pytest.raises(MotionFailedError) as refused:
            left.move_line(toward, speed=0.1)
        assert_refused(
            str(refused.value),
            r"path refused: segment 1 of 1, \d+\.\d\d s into the motion, object at \(.*\) m: "
            r"'left/link\d' would (come within \d+\.\d mm of|overlap) 'right/link\d'",
        )
        demand = k.servo.level.joints["demand"][left.span]
        np.testing.assert_array_equal(demand, start)  # nothing moved
        left.move_joints(start - turn, speed=0.3)  # away: it runs
        left.move_joints(start, speed=0.3)
        left.move_line(pose(here[:3, 3] - np.array([0.0, 0.1, 0.0]), here), speed=0.1)
        assert k.inst.fault_text() is None


def assert_refused(message: str, pattern: str) -> None:
    """A refusal's words match ``pattern``, the subsystem named once ("motion: request 3
    refused: joint move refused: ...")."""
    import re

    assert re.search(pattern, message), message
    assert message.count("motion:") == 1, message


def solid_table(tmp_path: Path, tools_touch: bool = True) -> dict[str, str]:
    """The shipped scene with its table solid to the arms' links (and, ``tools_touch``
    false, not for the tools to touch either): a config edit naming it."""
    text = DEFAULT_SCENE.read_text()
    loose = "    at: [0.0, -0.38, 0.2]\n    fixed: true\n    arms_touch: false\n"
    assert text.count(loose) == 1
    solid = "    at: [0.0, -0.38, 0.2]\n    fixed: true\n"
    if not tools_touch:
        solid += "    tools_touch: false\n"
    path = tmp_path / "solid-table.yaml"
    path.write_text(text.replace(loose, solid))
    return {r"^version: 1$": f"version: 1\nscene: {path}"}


def test_a_joint_move_into_a_solid_table_is_refused_and_one_clear_of_it_runs(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """Lockstep, a scene whose table the arms' links touch: the left arm's waist turned
    towards the table and its shoulder lowered, in one joint move, would put its wrist into
    the table (refused naming the link and the table); turned further first, then lowered
    beside the table, it runs, and the plant's arm meets nothing."""
    name = kali(lockstep=True, edits=solid_table(tmp_path))
    with Kali(name) as k:
        k.ready(["left"])
        left = k.robot("left")
        start = k.servo.level.joints["demand"][left.span].copy()
        with pytest.raises(MotionFailedError) as refused:
            left.move_joints(start + np.radians([-30, -30, 0, 0, 0, 0]), speed=0.3)
        assert_refused(
            str(refused.value),
            r"joint move refused: .*'left/link5' would (overlap 'table' by|come within "
            r"\d+\.\d mm of 'table')",
        )
        left.move_joints(start + np.radians([-70, 0, 0, 0, 0, 0]), speed=0.3)
        clear = start + np.radians([-70, -30, 0, 0, 0, 0])
        left.move_joints(clear, speed=0.3)
        left.settle()
        assert k.distance("left", "table").distance > 0.01
        assert np.abs(k.sim.truth("left").q - clear).max() < 2e-3
        assert k.inst.fault_text() is None


def test_the_clearance_walk_stops_at_the_first_pose_every_pair_measured_would() -> None:
    """``ClearanceWalk`` skips poses (its margin and the arms' reach bound what it may) yet
    finds the first pose of a path within the clearance exactly where coal's distance of
    every pair, pose by pose, finds it, and none where there is none: random two-arm paths
    near the walled scene, in coarse steps (at the TG's, it looks far less often: bench_tg's
    ``looks``)."""
    import coal

    from kali_daemons.robots.collision import CellClearance, CellGeometry

    cfg = make_config("collision-walk")
    cell = CellClearance(CellGeometry(cfg.robots, parse_scene(WALLED, "walled.yaml")))
    rng = np.random.default_rng(563)
    home = np.array(cfg.robots[0].type.q_home)

    def exact(qs: list[np.ndarray]) -> float:
        cell.gap(qs)  # places the arms' shapes
        least = np.inf
        for i, j in zip(cell.pair_a, cell.pair_b, strict=True):
            a, b = cell.geometry_of(int(i)), cell.geometry_of(int(j))
            at_a, at_b = cell.placement(int(i)), cell.placement(int(j))
            d = coal.distance(a, at_a, b, at_b, coal.DistanceRequest(), coal.DistanceResult())
            least = min(least, d)
        return float(least)

    hits = looks = poses = 0
    for _ in range(12):
        ends = [home + rng.uniform(-0.9, 0.9, 6) for _ in range(2)]
        path = [[home + (e - home) * s for e in ends] for s in np.linspace(0.0, 1.0, 60)]
        first = next((i for i, qs in enumerate(path) if exact(qs) < cell.clearance), None)
        walk = cell.walk([0, 1], path[0])
        said = [walk.hit(qs) for qs in path]
        found = next((i for i, near in enumerate(said) if near is not None), None)
        assert found == first
        if found is not None:  # and says that pose's distance, coal's least of every pair
            assert said[found].distance == pytest.approx(exact(path[found]), abs=1e-9)
        hits += first is not None
        looks += walk.looks
        poses += len(path) if found is None else found + 1
    assert 0 < hits < 12 and looks < poses  # some skipped, even at these coarse steps


def test_a_walk_starting_within_the_clearance_may_move_away_and_not_nearer() -> None:
    """Arms that start a motion within the clearance (a held part resting on a fixture its
    tool may not touch, say) may move away, but not nearer than they started: the left arm's
    waist turned towards the right arm until within the clearance, a walk from there lets it
    turn back out and refuses it going further in; once out, the clearance holds again (back
    in is refused at its edge)."""
    from kali_daemons.robots.collision import CellClearance, CellGeometry

    cfg = make_config("collision-away")
    cell = CellClearance(CellGeometry(cfg.robots, parse_scene(WALLED, "walled.yaml")))
    home = np.array(cfg.robots[0].type.q_home)
    other = np.array(cfg.robots[1].type.q_home)
    turn = np.zeros(6)
    for waist in np.radians(np.arange(0.0, 180.0, 0.5)):  # towards the right arm until near
        turn[0] = waist
        least, near = cell.gap([home + turn, other])
        if least < cell.clearance / 2:
            break
    assert near is not None and near.near_b.startswith("right/") and least > -0.01
    inside = home + turn
    out = home + turn - np.radians([20.0, 0, 0, 0, 0, 0])
    walk = cell.walk([0], [inside, other])
    path = [inside + (out - inside) * s for s in np.linspace(0.0, 1.0, 40)]
    assert all(walk.refused([q]) is None for q in path)  # away, and out of it
    back = [out + (inside - out) * s for s in np.linspace(0.0, 1.0, 40)]
    said = [walk.refused([q]) for q in back]  # back in: refused where the clearance begins
    first = next(i for i, near in enumerate(said) if near is not None)
    gaps = [cell.gap([back[i], other])[0] for i in (first - 1, first)]
    assert gaps[1] < cell.clearance <= gaps[0]
    walk = cell.walk([0], [inside, other])
    further = inside + np.radians([2.0, 0, 0, 0, 0, 0])
    near = walk.refused([further])
    assert near is not None and near.near_b.startswith("right/") and near.distance < least


def test_a_stream_driven_into_a_solid_table_slows_and_stops_at_the_clearance(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """Lockstep, a table neither the arms' links nor their tools may touch: the left tool,
    streamed 20 cm down through the table's top, slows as its arm nears the table and comes
    to rest at the clearance, the stream running on with no fault (MoveIt Servo's rule, not a
    refusal or a halt); streamed up again, it follows."""
    name = kali(lockstep=True, edits=solid_table(tmp_path, tools_touch=False))
    with Kali(name) as k:
        k.ready(["left"])
        left = k.robot("left")
        left.move_joints(left.joints_at(pose([-0.15, -0.38, 0.56], DOWN), "run"), speed=0.3)
        left.settle()
        clearance = k.scene.clearance_m
        with left.stream(lifetime=0.5, speed=0.1) as s:
            start = left.read_pose(demand=True)
            down = pose(start[:3, 3] - np.array([0.0, 0.0, 0.2]), start)
            heights, gaps = [], []
            for _ in range(400):  # 8 s
                s.send(down)
                step_kali_clock(k.inst, 20)
                heights.append(float(left.read_pose(demand=True)[2, 3]))
                gaps.append(k.distance("left", "table").distance)
            assert s.handle.state == RequestState.RUNNING, s.handle.message
            assert k.inst.fault_text() is None
            speeds = -np.diff(heights) / 0.02
            assert speeds[:10].max() > 0.09  # at the stream's speed, far from the table
            assert abs(speeds[-10:]).max() < 1e-6  # at rest at the end
            assert clearance - 1e-3 < gaps[-1] < clearance + 2e-3, gaps[-10:]
            assert min(gaps) > clearance - 1e-3
            near = [v for v, g in zip(speeds, gaps[1:], strict=True) if g < clearance + 0.02]
            assert max(near) < 0.05  # slower within 2 cm of the clearance
            for _ in range(75):  # and back up, at the stream's speed
                s.send(start)
                step_kali_clock(k.inst, 20)
            assert k.distance("left", "table").distance > clearance + 0.05
            assert s.handle.state == RequestState.RUNNING


def test_a_joint_stream_towards_the_other_arm_holds_at_the_clearance(
    kali: Callable[..., str],
) -> None:
    """Lockstep, the shipped cell: the left arm's waist streamed 40° towards the right arm
    stops with the arms the clearance apart (not slowed before it: a joint stream has no
    direction to the nearest body), the stream running on with no fault; streamed back, it
    follows."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready(["left", "right"])
        left = k.robot("left")
        start = k.start_point(left.index)
        clearance = k.scene.clearance_m
        js = left.stream_joints(lifetime=0.5, speed=0.3)
        try:
            toward = start + np.radians([40, 0, 0, 0, 0, 0])
            for _ in range(150):  # 3 s
                js.send(toward)
                step_kali_clock(k.inst, 20)
            held = k.servo.level.joints["demand"][left.span].copy()
            assert js.handle.state == RequestState.RUNNING, js.handle.message
            assert k.inst.fault_text() is None
            assert start[0] < held[0] < toward[0]
            step_kali_clock(k.inst, 300)
            assert clearance - 2e-3 < k.distance("left", "right").distance < clearance + 5e-3
            for _ in range(100):
                js.send(start)
                step_kali_clock(k.inst, 20)
            assert np.abs(k.servo.level.joints["demand"][left.span] - start).max() < 1e-9
        finally:
            js.close()


def test_a_held_part_is_checked_with_the_arm_that_holds_it(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """Lockstep, the parts' scene with its table solid and untouchable by the tools: the left
    arm grips the block naming it held (``grip(holding=...)``: its load record names the
    object) and lifts it off the table it rests on (within the clearance, moving away); a
    line that would push the block 2 cm into the table, the arm itself staying clear, is
    refused naming the held block and the table; one that keeps it above runs; let go, the
    same line runs (the block stays behind); a set_load naming what no arm can hold is
    refused."""
    text = (DEFAULT_SCENE.parent / "parts.yaml").read_text()
    loose = "    at: [0.0, -0.38, 0.2]\n    fixed: true\n    arms_touch: false\n"
    assert text.count(loose) == 1
    solid = "    at: [0.0, -0.38, 0.2]\n    fixed: true\n    tools_touch: false\n"
    scene = tmp_path / "solid-parts.yaml"
    scene.write_text(text.replace(loose, solid))
    name = kali(lockstep=True, edits={r"^version: 1$": f"version: 1\nscene: {scene}"})
    with Kali(name) as k:
        k.ready(["left"])
        left = k.robot("left")
        site = k.scene.object("block").pose @ k.scene.grasp_for("block", k.inst.config.robots[0])
        above = site.copy()
        above[2, 3] += 0.05
        left.move_joints(left.joints_at(above, "run"), speed=0.5, timeout=30)
        left.move_line(site, speed=0.05, timeout=30)
        left.grip(True, holding="block")  # resting on the table: within the clearance
        step_kali_clock(k.inst, 50)
        assert k.sim.truth("left").held == "block"
        left.move_line(above, speed=0.05, timeout=30)
        block = [o.name for o in k.scene.objects].index("block") + 1  # the record's: index + 1
        assert int(k.loads["held"][left.index]) == block
        into = above.copy()
        into[2, 3] -= 0.07  # the block 2 cm into the table's top, the flange 6.5 cm over it
        with pytest.raises(MotionFailedError) as refused:
            left.move_line(into, speed=0.05)
        assert_refused(
            str(refused.value),
            r"path refused: .*'left/block' would (overlap 'table' by|come within \d+\.\d mm of "
            r"'table')",
        )
        over = above.copy()
        over[2, 3] -= 0.03  # its bottom 2 cm over the table
        left.move_line(over, speed=0.05, timeout=30)
        left.grip(False)
        assert int(k.loads["held"][left.index]) == 0
        left.move_line(above, speed=0.05, timeout=30)
        left.move_line(into, speed=0.05, timeout=30)  # nothing held: the arm stays clear
        can = r"those are \['bar', 'block', 'can', 'ball'\]"
        with pytest.raises(ServoError, match=rf"holding 'stand': not an object .* hold; {can}"):
            left.set_load(0.2, holding="stand")
        assert k.inst.fault_text() is None
