"""Scenes from files (issue 56 item 1): the cell's world read from a scene file, the shipped
cell's as the default scene, several objects any of which a gripper holds, and a scene file
that is wrong refused naming the file, the object and the rule."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.client import Kali, pose
from kali_daemons.core import layout
from kali_daemons.core.errors import ConfigError, MotionError
from kali_daemons.core.layout import RequestState
from kali_daemons.plant.sim import PlantSim
from kali_daemons.robots.cell import check_scene_apart
from kali_daemons.robots.scene import DEFAULT_SCENE, load_scene, parse_scene
from kali_daemons.wallclock import step_kali_clock
from tests.conftest import ROOT, make_config

PARTS = (ROOT / "config" / "scenes" / "parts.yaml").resolve()
WITH_PARTS = {r"^version: 1$": "version: 1\nscene: scenes/parts.yaml"}
DOWN = np.diag([1.0, -1.0, -1.0])  # the flange's z straight down (the parts' grasps)


def test_the_default_scene_is_the_shipped_cell() -> None:
    """A stand, a table and the bar on the stand; the bar's grasps above its ends, each arm
    taking the end nearer its base, the flange's z down and its x along the bar away from the
    middle (the cell as it was built before scenes: cell.py's constants)."""
    scene = load_scene(DEFAULT_SCENE)
    assert [o.name for o in scene.objects] == ["stand", "table", "bar"]
    assert [o.name for o in scene.free] == ["bar"] and scene.belt == "bar"
    bar = scene.object("bar")
    assert (bar.shape, bar.size, bar.mass) == ("box", (0.36, 0.04, 0.04), 1.5)
    np.testing.assert_array_equal(bar.pose[:3, 3], [0.0, 0.0, 0.565 + 0.02])
    cfg = make_config("scene-default")
    left, right = cfg.robots
    expected = {
        "left": ([-0.16, 0.0, 0.065], np.diag([-1.0, 1.0, -1.0])),
        "right": ([0.16, 0.0, 0.065], np.diag([1.0, -1.0, -1.0])),
    }
    for robot in (left, right):
        grasp = scene.grasp_for("bar", robot)
        xyz, rotation = expected[robot.name]
        np.testing.assert_array_equal(grasp[:3, 3], xyz)
        np.testing.assert_array_equal(grasp[:3, :3], rotation)  # exact: quarter turns
    turned = scene.grasp_for("bar", dataclasses.replace(left, grasp_yaw_deg=180.0))
    np.testing.assert_array_equal(turned[:3, :3], np.diag([1.0, -1.0, -1.0]))


def test_the_plant_builds_every_object_and_records_its_truth(arena: object) -> None:
    """The parts' scene in the plant: every free object a body whose pose is its truth
    record's, in the scene's order, resting where the file puts it; a weld per arm and
    graspable object; a grasp site per grasp."""
    cfg = make_config("scene-plant", WITH_PARTS)
    sim = PlantSim(cfg, arena)  # type: ignore[arg-type]
    assert sim.world.objects == ("bar", "block", "can", "ball")
    assert [len(w) for w in sim.world.weld] == [4, 4] and sim.model.neq == 8
    assert len(sim.world.grasp_site) == 2 + 1 + 1 + 1
    for _ in range(200):
        sim.cycle()
    for obj, truth in zip(cfg.scene.free, sim.object_truth, strict=True):
        np.testing.assert_allclose(truth["pose"][:3], obj.xyz, atol=2e-3)  # settled in place
    assert [int(t["held"]) for t in sim.truth] == [-1, -1]


def test_an_arm_picks_up_and_puts_down_each_part(kali: Callable[..., str]) -> None:
    """Lockstep, the parts' scene: the left arm goes above each part's grasp, down onto it,
    grips (the plant welds the part whose grasp is in reach: the truth names it), lifts it
    5 cm, carries it 4 cm along +x, puts it down and lets go; the part lies 4 cm from where it
    was, on the table, and nothing else moved.  A motion system holding an object that is
    not in the scene is refused, naming the scene's objects."""
    name = kali(lockstep=True, edits=WITH_PARTS)
    with Kali(name) as k:
        k.ready(["left"])
        left = k.robot("left")
        left.feedforward("full")
        scene = k.scene
        objects = k.inst.arena.existing(layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, 4)
        arms = k.inst.arena.existing(layout.KEY_TRUTHS, layout.ARM_TRUTH, 2)
        step_kali_clock(k.inst, 300)
        for index, part in enumerate(("block", "can", "ball"), start=1):
            before = objects["pose"][:, :3].copy()
            site = scene.object(part).pose @ scene.grasp_for(part, k.inst.config.robots[0])
            np.testing.assert_allclose(site[:3, :3], DOWN, atol=1e-12)
            above = site.copy()
            above[2, 3] += 0.05
            left.move_joints(left.joints_at(above, "run"), speed=0.5, timeout=30)
            left.move_line(site, speed=0.05, timeout=30)
            step_kali_clock(k.inst, 300)
            left.grip(True)
            step_kali_clock(k.inst, 50)
            assert int(arms["held"][0]) == index, part
            assert k.sim.truth("left").held == part
            placed = site.copy()
            placed[0, 3] += 0.04
            lifted = placed.copy()
            lifted[2, 3] += 0.05
            h = left.move_path([above, lifted, placed], speed=0.05, transition_s=0.1, wait=False)
            for _ in range(1000):
                step_kali_clock(k.inst, 10)
                if h.done:
                    break
            assert h.state == RequestState.DONE, h.message
            step_kali_clock(k.inst, 300)
            left.grip(False)
            step_kali_clock(k.inst, 300)
            assert int(arms["held"][0]) == -1
            after = objects["pose"][:, :3].copy()
            moved = after[index] - before[index]
            np.testing.assert_allclose(moved, [0.04, 0.0, 0.0], atol=3e-3)
            others = np.delete(np.arange(4), index)
            np.testing.assert_allclose(after[others], before[others], atol=1e-3)
            left.move_line(left.read_pose() @ pose([0.0, 0.0, -0.05]), speed=0.05, timeout=30)
        with pytest.raises(MotionError, match=r"no object 'peg' in the scene; objects: stand"):
            k.motion_system(["left"], holding="peg")
        assert k.inst.fault_text() is None


BAD = [
    ("version: 1\nobjects: [", "line 2, column 11: YAML does not parse"),
    ("version: 2\nobjects: []", "version = 2: this Kali reads scene files of version 1"),
    ("version: 1\nthings: []", "'things' is not a key of the top level"),
    (
        "version: 1\nobjects:\n  - {name: cube, shape: box, size: [0.1, 0.1, 0.1], at: [0, 0, 1]}",
        "objects[0] ('cube'): mass = None: a free object needs a mass > 0 kg",
    ),
    (
        "version: 1\nobjects:\n  - {name: cube, shape: cone, size: [0.1], at: [0, 0, 1]}",
        "objects[0] ('cube'): shape = 'cone': one of box, cylinder, capsule, sphere",
    ),
    (
        "version: 1\nobjects:\n  - {name: cube, shape: box, size: [0.1, 0.1], at: [0, 0, 1]}",
        "objects[0] ('cube'): size = [0.1, 0.1]: a list of 3 finite numbers",
    ),
    (
        "version: 1\nobjects:\n  - {name: wall, shape: box, size: [1, 1, 1], at: [0, 0, 1],"
        " fixed: true, grasps: [{name: g, at: [0, 0, 1]}]}",
        "objects[0] ('wall'): grasps: a fixed object cannot be held",
    ),
    (
        "version: 1\nobjects:\n  - {name: a, shape: sphere, size: [0.1], at: [0, 0, 1], mass: 1}\n"
        "  - {name: a, shape: sphere, size: [0.1], at: [0, 0, 2], mass: 1}",
        "objects[1]: name 'a' given twice",
    ),
    (
        "version: 1\nobjects:\n  - {name: wall, shape: box, size: [1, 1, 1], at: [0, 0, 1],"
        " fixed: true}\nbelt: wall",
        "belt = 'wall': must name a free object the conveyor carries",
    ),
    (
        "version: 1\nobjects: []\nclearance_m: 2",
        "clearance_m = 2: a distance in metres, 0 .. 0.5 (how near a checked motion lets an "
        "arm come to another arm or to an object its links touch)",
    ),
    ("version: 1\nobjects: []\nclearance_m: near", "clearance_m = 'near': a distance in metres"),
]


@pytest.mark.parametrize(("text", "message"), BAD)
def test_a_wrong_scene_file_is_refused_naming_the_file_and_the_rule(
    text: str, message: str
) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_scene(text, "my-scene.yaml")
    assert "my-scene.yaml: " in str(caught.value) and message in str(caught.value)


def test_fixed_objects_that_overlap_are_refused_before_anything_runs() -> None:
    scene = parse_scene(
        "version: 1\nobjects:\n"
        "  - {name: table, shape: box, size: [1, 1, 0.4], at: [0, 0, 0.2], fixed: true}\n"
        "  - {name: post, shape: cylinder, size: [0.05, 1], at: [0.5, 0, 0.5], fixed: true}\n"
        "  - {name: shelf, shape: box, size: [1, 1, 0.1], at: [0, 0, 1.05], fixed: true}",
        "lab.yaml",
    )
    with pytest.raises(ConfigError, match=r"lab.yaml: fixed objects 'table' and 'post' overlap"):
        check_scene_apart(scene)
    check_scene_apart(load_scene(PARTS))  # touching is allowed: the parts on the table


def test_the_config_names_its_scene_and_a_belt_needs_an_object(tmp_path: Path) -> None:
    """``scene:`` is taken relative to the config file and must exist; a conveyor in a scene
    that names no object for it is refused at the config."""
    cfg = make_config("scene-parts", WITH_PARTS)
    assert cfg.scene.source == str(PARTS) and len(cfg.scene.free) == 4
    with pytest.raises(ConfigError, match=r"scene = 'scenes/nowhere.yaml': no such file"):
        make_config("scene-missing", {r"^version: 1$": "version: 1\nscene: scenes/nowhere.yaml"})
    bare = tmp_path / "bare.yaml"
    bare.write_text("version: 1\nobjects: []\n")
    edits = {
        r"^version: 1$": f"version: 1\nscene: {bare}",
        r"^  conveyor_m_s: .*$": "  conveyor_m_s: [0.0, 0.02]",
    }
    with pytest.raises(ConfigError, match=r"plant.conveyor_m_s = \[0.0, 0.02\]: a belt needs"):
        make_config("scene-belt", edits)
