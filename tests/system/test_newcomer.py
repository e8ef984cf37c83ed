"""The newcomer's path: what the README and the docs tell a user to type works as written.

- every ``kalictl`` line of the README, of the pages under ``docs/`` and of
  ``scripts/demo.sh`` is accepted by the real command line's parser (a renamed option or a
  changed unit, like a move's ``--speed``, fails here rather than in front of a new user);
- the README's complete robot program runs, copied out of the README, under ``kalictl run``,
  and the programs guide shows the same program;
- the servo guide's plugin steps (``docs/guide/servos.md``), followed literally, give a new
  algorithm a joint can switch to while it holds, tuned on line.

Lockstep instances (a waiting program steps the clock itself), so the results do not depend
on the machine's load.
"""

from __future__ import annotations

import re
import shlex
import shutil
import warnings
from collections.abc import Callable
from pathlib import Path

import click
import pytest

from kali_daemons.runtime.instance import Instance
from kali_daemons.servo.client import ServoClient
from kali_daemons.tools import cli
from kali_daemons.wallclock import step_kali_clock

from ..conftest import ROOT, config_text, unique_name
from ..test_launcher import kalictl

README = (ROOT / "README.md").read_text()
DOCS = {p.relative_to(ROOT).as_posix(): p.read_text() for p in sorted(ROOT.glob("docs/**/*.md"))}
DEMO = (ROOT / "scripts" / "demo.sh").read_text()


def section(text: str, title: str, where: str = "README") -> str:
    """The text under ``## title`` in ``text``, up to the next ``## `` section or the end."""
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, re.M | re.S)
    assert m, f"{where} has no section '{title}'"
    return m.group(1)


def code_blocks(text: str, lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", text, re.S)


def kalictl_lines() -> list[list[str]]:
    """Every kalictl command a user is shown: demo.sh's and the bash blocks' of the README and
    of every page under docs/."""
    lines = [ln for ln in DEMO.splitlines() if not ln.startswith(("trap ", "kalictl="))]
    for text in [README, *DOCS.values()]:
        for block in code_blocks(text, "bash"):
            lines += block.splitlines()
    out: list[list[str]] = []
    for ln in lines:
        lex = shlex.shlex(ln, posix=True, punctuation_chars=True)
        lex.whitespace_split = True
        command: list[str] = []
        for word in [*lex, ";"]:  # commands end at ; && || | and the line's end
            if word not in (";", "&&", "||", "|"):
                command.append(word)
                continue
            if command and command[0] in ("kalictl", "$kalictl"):
                out.append(command[1:])
            command = []
    return out


def unparsed(ctx: click.Context) -> list[str]:
    """A group's tokens left for its subcommand (click 8 keeps the command's name apart, in
    ``protected_args``, deprecated for 9.0 where ``args`` holds them all)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        return [*ctx.protected_args, *ctx.args]


def parse(args: list[str]) -> None:
    """Resolve ``args`` through the kalictl group down to its command, as click would."""
    ctx = cli.main.make_context("kalictl", list(args))
    with ctx:
        group: click.Group = cli.main
        while rest := unparsed(ctx):
            name, cmd, rest = group.resolve_command(ctx, rest)
            assert cmd is not None, f"no command {name!r}"
            ctx = cmd.make_context(name, rest, parent=ctx)
            if not isinstance(cmd, click.Group):
                break
            group = cmd


def test_every_kalictl_line_shown_to_a_user_parses() -> None:
    lines = kalictl_lines()
    assert len(lines) > 40, lines  # demo.sh and the docs have more: the extraction works
    for args in lines:
        try:
            parse(args)
        except click.exceptions.Exit:
            pass  # --help
        except click.ClickException as exc:
            pytest.fail(f"kalictl {shlex.join(args)}: {exc.format_message()}")


def test_the_readmes_program_runs_as_written(kali: Callable[..., str], tmp_path: Path) -> None:
    (program,) = code_blocks(section(README, "A robot program"), "python")
    guide = "docs/guide/programs.md"
    shown = code_blocks(section(DOCS[guide], "Moving arms from a program", guide), "python")
    assert shown and shown[0] == program, f"{guide} shows another program than the README"
    path = tmp_path / "wave.py"
    path.write_text(program)
    name = kali(lockstep=True)
    r = kalictl("-i", name, "run", str(path))
    assert r.returncode == 0, r.stdout + r.stderr
    assert re.search(r"left tool at \[", r.stdout), r.stdout


def test_the_readmes_servo_plugin_steps_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Copy the example, rename it, name it in the config, start, select it, tune it."""
    guide = "docs/guide/servos.md"
    steps = section(DOCS[guide], "Writing a servo algorithm", guide)
    assert "cp kali_daemons/examples/servo_plugin_example.py" in steps
    assert 'NAME = "mine"' in steps
    mine = tmp_path / "my_servo.py"
    shutil.copy(ROOT / "kali_daemons" / "examples" / "servo_plugin_example.py", mine)
    text = mine.read_text()
    assert text.count('NAME = "bwpd"') == 1
    mine.write_text(text.replace('NAME = "bwpd"', 'NAME = "mine"'))
    name = unique_name("nc")
    config = tmp_path / "kali.yaml"
    config.write_text(
        config_text(name, {r"^plugins: \[(.*)\]$": r"plugins: [\1, my_servo.py]"})
    )  # relative to the config file, as the servo guide says
    monkeypatch.setenv("KALI_LOG_DIR", str(tmp_path / "logs"))
    r = kalictl("start", "-c", str(config), "--lockstep")
    try:
        assert r.returncode == 0, r.stdout + r.stderr
        listing = kalictl("-i", name, "servo", "list")
        assert re.search(r"^mine\s+joint\s+bandwidth_hz, inertia$", listing.stdout, re.M), (
            listing.stdout
        )
        with Instance.attach(name) as inst:
            step_kali_clock(inst, 30)
            assert kalictl("-i", name, "enable").returncode == 0
            step_kali_clock(inst, 2000)
            r = kalictl("-i", name, "servo", "select", "left", "1", "mine")
            assert r.returncode == 0 and "left joint 1: mine" in r.stdout, r.stdout + r.stderr
            step_kali_clock(inst, 20)
            r = kalictl("-i", name, "servo", "set", "left", "1", "bandwidth_hz=6", "inertia=4.4")
            assert r.returncode == 0, r.stdout + r.stderr
            step_kali_clock(inst, 1000)
            client = ServoClient(inst)
            try:
                assert client.active("left", 1) == "mine"
                assert client.get_params("left", 1)["bandwidth_hz"] == 6.0
                error = abs(float(client.level.arm("demand", 0)[0] - client.level.arm("q", 0)[0]))
                assert error < 1e-3, f"joint 1 holds under 'mine': error {error} rad"
            finally:
                client.close()
            assert inst.fault_text() is None
    finally:
        stop = kalictl("-i", name, "stop")
        assert stop.returncode == 0, stop.stderr
