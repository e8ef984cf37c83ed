"""Robot types (issue 25): found by name, declared whole, refused with the field and rule."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kali_daemons.core.errors import ConfigError
from kali_daemons.robots import MAX_JOINTS, known_types, puma560, robot_type
from kali_daemons.robots.profile import read_only

from .test_launcher import kalictl

PUMA = puma560.ROBOT


def test_types_are_found_by_name_and_unknown_ones_are_named() -> None:
    assert robot_type("puma560") is PUMA
    assert "puma560" in known_types()
    with pytest.raises(ConfigError, match=r"robot type 'kuka': no such type \(known: .*puma560"):
        robot_type("kuka")
    with pytest.raises(ConfigError, match=r"robot type '\.\./x': not a type name"):
        robot_type("../x")


def test_the_puma_declares_its_facts_in_one_place() -> None:
    assert PUMA.n_joints == 6 and PUMA.urdf.is_file()
    np.testing.assert_array_equal(PUMA.drive.armature, puma560.ARMATURE)
    np.testing.assert_array_equal(PUMA.q_home, puma560.QN)
    assert PUMA.pid_defaults == puma560.PID_DEFAULTS
    assert len(PUMA.kinematics.configs) == 8
    assert str(PUMA.kinematics.config_of(puma560.QN)) == "ruf"
    assert PUMA.kinematics.singular(puma560.QN) is None
    assert "wrist singularity" in PUMA.kinematics.singular(puma560.QZ)


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"n_joints": 9}, r"n_joints = 9: must be 1 \.\. 8"),
        ({"q_max": read_only([1.0] * 5)}, r"q_max = .*: must be 6 finite numbers, one per joint"),
        ({"qd_max": read_only([1.0, 1, 1, 1, 1, np.nan])}, r"qd_max = .*: must be 6 finite"),
        ({"q_home": read_only([4.0] * 6)}, r"q_home = .*: must be within q_min \.\. q_max"),
        ({"pid_defaults": ({},) * 5}, r"pid_defaults = 5: must have 6 entries"),
        ({"index_phases": read_only([7.0] * 6)}, r"index_phases = .*: must be 6 motor angles"),
        ({"urdf": PUMA.urdf.with_name("nope.urdf")}, r"urdf = '.*nope\.urdf': no such file"),
    ],
)
def test_a_bad_declaration_is_refused_naming_the_field_and_rule(change: dict, says: str) -> None:
    with pytest.raises(ConfigError, match=rf"robot type 'puma560': {says}"):
        dataclasses.replace(PUMA, **change)
    assert MAX_JOINTS == 8


def test_kalictl_types_lists_them() -> None:
    r = kalictl("types")
    assert r.returncode == 0, r.stderr
    assert "puma560      6 joints  Unimation PUMA 560" in r.stdout


def test_the_fr3s_collision_cylinders_hold_franky_sims_collision_meshes() -> None:
    """Every vertex of franky-sim's collision mesh of each FR3 link (the simulator's, from
    franka_description) lies inside that link's cylinder in fr3.urdf, as Pinocchio loads it
    for the controller's collision model; and scripts/gen_fr3_collision.py, which wrote them,
    finds the file current."""
    import importlib.util
    from pathlib import Path

    import pinocchio as pin

    path = Path(__file__).resolve().parent.parent / "scripts" / "gen_fr3_collision.py"
    spec = importlib.util.spec_from_file_location("gen_fr3_collision", path)
    assert spec is not None and spec.loader is not None
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    assert gen.main(["--check"]) == 0
    urdf = str(robot_type("fr3").urdf)
    model = pin.buildModelFromUrdf(urdf)
    shapes = pin.buildGeomFromUrdf(model, urdf, pin.COLLISION)
    franky = gen.franky_model()
    assert len(shapes.geometryObjects) == 8
    for link, g in enumerate(shapes.geometryObjects):
        frame = model.frames[g.parentFrame]
        assert frame.name == ("base_link" if link == 0 else f"link{link}")
        # the vertices in the link's frame, then in the cylinder's
        at = frame.placement.inverse() * g.placement  # (a link's frame sits on its joint)
        points = gen.link_vertices(franky, link)
        local = (points - at.translation) @ at.rotation  # rows: Rᵀ (p - t)
        radius, half = g.geometry.radius, g.geometry.halfLength
        assert np.hypot(local[:, 0], local[:, 1]).max() <= radius, link
        assert np.abs(local[:, 2]).max() <= half, link
