"""The config's declarations seen by a user: ``kalictl config schema`` (a JSON Schema every
shipped file meets), ``kalictl config show`` (every default written out), an instance named
with ``-i`` instead of in the file, and an unknown key refused with a suggestion."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest
import yaml

from kali_daemons.core.errors import ConfigError
from kali_daemons.runtime import config as config_mod
from kali_daemons.runtime.config import ConfigFile, load_config, parse_config, schema, show
from kali_daemons.runtime.instance import Instance

from .conftest import ROOT, config_text, leftovers, unique_name
from .test_launcher import kalictl

SHIPPED = sorted((ROOT / "config").glob("*.yaml"))


@pytest.fixture(autouse=True)
def _fixed_cpu_count(monkeypatch: pytest.MonkeyPatch) -> None:
    """Four CPUs, so the shipped files' bindings hold on any machine."""
    monkeypatch.setattr(config_mod, "_cpu_count", lambda: 4)


def test_kalictl_config_schema_prints_a_json_schema_every_shipped_file_meets() -> None:
    r = kalictl("config", "schema")
    assert r.returncode == 0, r.stderr
    printed = json.loads(r.stdout)
    assert printed == schema()
    jsonschema.Draft202012Validator.check_schema(printed)
    validator = jsonschema.Draft202012Validator(printed)
    for path in SHIPPED:
        doc = yaml.safe_load(path.read_text())
        assert [e.message for e in validator.iter_errors(doc)] == [], path.name
    # each field carries its declaration: type, default, bounds, unit, description
    clock = printed["$defs"]["ClockConfig"]["properties"]["busy_wait_us"]
    assert (clock["type"], clock["default"], clock["minimum"], clock["maximum"]) == (
        "integer",
        0,
        0,
        500,
    )
    assert clock["unit"] == "us" and clock["description"]
    servo = printed["$defs"]["ClockConfig"]["properties"]["servo_period_ms"]
    assert (servo["type"], servo["exclusiveMinimum"], servo["maximum"]) == ("number", 0, 60000)
    assert not any(f'"{bound}":' in r.stdout for bound in ("ge", "gt", "le", "lt"))
    # a process kind's entry holds only its keys, with its kind's defaults
    tg = printed["$defs"]["Process_tg"]
    assert list(tg["properties"]) == ["cpu", "priority", "serious", "stage"]
    assert tg["properties"]["stage"]["default"] == 1 and tg["additionalProperties"] is False
    doc = yaml.safe_load((ROOT / "config" / "default.yaml").read_text())
    doc["clock"]["busy_wait"] = 0
    assert any("busy_wait" in e.message for e in validator.iter_errors(doc))


def test_config_show_writes_every_default_and_reads_back_the_same() -> None:
    minimal = parse_config("version: 1\ninstance: x\nrobots: [{name: a}]\n", "<minimal>")
    shown = show(minimal)
    doc = yaml.safe_load(shown)
    # every declared top-level key, every key of a section and of a robot's entry
    assert list(doc) == list(ConfigFile.__pydantic_fields__)
    assert doc["clock"]["busy_wait_us"] == 0 and doc["plant"]["watchdog_ms"] == 20.0
    assert doc["processes"]["sv"]["poll_us"] == 200 and doc["processes"]["sv"]["rest_ms"] == 4
    assert doc["processes"]["viewer"]["period_ms"] == 40
    robot = doc["robots"][0]
    assert (robot["model"], robot["ff"], robot["ft"]["sensor"]) == ("puma560", "off", "mini45")
    assert robot["safe_rad"] == [0.15] * 6 and len(robot["index_phases_deg"]) == 6
    again = parse_config(shown, "<shown>")
    assert show(again).splitlines()[1:] == shown.splitlines()[1:]
    assert again.processes == minimal.processes and again.clock == minimal.clock
    assert again.robots[0].ft == minimal.robots[0].ft


def test_kalictl_config_show_reads_a_file_and_refuses_a_bad_one(tmp_path: Path) -> None:
    r = kalictl("config", "show", "-c", str(ROOT / "config" / "mixed.yaml"))
    assert r.returncode == 0, r.stderr
    doc = yaml.safe_load(r.stdout)
    assert [robot["model"] for robot in doc["robots"]] == ["puma560", "panda"]
    assert doc["dashboard"]["server_memory_mib"] == 256  # not in the file: its default
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\ninstance: x\nclock: {tick_ms: 1}\n")
    r = kalictl("config", "show", "-c", str(bad))
    assert r.returncode == 1 and "clock.tick_ms: unknown key" in r.stderr


def test_an_instance_named_with_i_needs_no_instance_in_the_file(tmp_path: Path) -> None:
    text = config_text("x").replace("instance: x\n", "")
    assert "instance:" not in text
    path = tmp_path / "k.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"instance: missing; .* kalictl -i NAME"):
        load_config(path)
    assert load_config(path, instance="cell-b").instance == "cell-b"
    with pytest.raises(ConfigError, match=r"instance = 'B/x': must be a string matching"):
        load_config(path, instance="B/x")
    # a file's own name is overridden by -i, and still checked
    named = tmp_path / "named.yaml"
    named.write_text(config_text("cell-a"))
    assert load_config(named, instance="cell-b").instance == "cell-b"

    r = kalictl("config", "show", "-c", str(path))
    assert r.returncode == 1 and "instance: missing" in r.stderr
    r = kalictl("-i", "cell-b", "config", "show", "-c", str(path))
    assert r.returncode == 0, r.stderr
    assert yaml.safe_load(r.stdout)["instance"] == "cell-b"


def test_kalictl_start_with_i_runs_a_file_without_instance(tmp_path: Path) -> None:
    """The daemons re-read the stored text under the instance's own name."""
    name = unique_name()
    path = tmp_path / "k.yaml"
    path.write_text(config_text("x").replace("instance: x\n", ""))
    env = {"KALI_LOG_DIR": str(tmp_path / "logs")}
    try:
        r = kalictl("-i", name, "start", "--lockstep", "-c", str(path), env=env)
        assert r.returncode == 0, r.stderr
        assert f"instance '{name}' started" in r.stdout
        with Instance.attach(name) as inst:
            assert inst.config.instance == name
            assert "instance:" not in inst.config.text
        r = kalictl("-i", name, "status", env=env)
        assert r.returncode == 0, r.stderr
    finally:
        kalictl("-i", name, "stop", env=env)
    assert leftovers(name) == ([], [])


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (
            ("  tool_mass_kg: 0.0", "  tool_mass_k: 0.0"),
            "robots[0].ft.tool_mass_k: unknown key (did you mean 'tool_mass_kg'?); allowed "
            "keys: sensor, tool_mass_kg, tool_com_m",
        ),
        (
            ("certificate: a.pem", "certificat: a.pem"),
            "bridge.tls.certificat: unknown key (did you mean 'certificate'?); allowed keys: "
            "certificate, private_key, root_ca",
        ),
        (
            ("poll_us: 200", "pol_us: 200"),
            "processes.sv.pol_us: unknown key (did you mean 'poll_us'?); allowed keys: count, "
            "cpus, priority, serious, stage, poll_us, rest_ms",
        ),
    ],
)
def test_an_unknown_nested_key_is_refused_at_its_dotted_path_with_a_suggestion(
    edit: tuple[str, str], expected: str
) -> None:
    text = (
        "version: 1\ninstance: x\n"
        "processes:\n"
        "  wallclock: {}\n  plant: {}\n  tg: {}\n  sio: {}\n  dynamics: {}\n  viewer: {}\n"
        "  sv: {poll_us: 200}\n"
        "robots:\n"
        "  - name: a\n"
        "    ft:\n"
        "      tool_mass_kg: 0.0\n"
        "bridge: {tls: {certificate: a.pem}}\n"
    )
    old, new = edit
    assert text.count(old) == 1
    with pytest.raises(ConfigError) as info:
        parse_config(text.replace(old, new), "k.yaml")
    assert str(info.value).startswith(f"config: k.yaml: {expected}")
