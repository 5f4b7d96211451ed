"""What people read: help (-h, --version, whole texts, flags as flags, defaults), progress lines and tables
in pipes and logs."""

from __future__ import annotations

import time

import click
import pytest
import typer
from typer.testing import CliRunner

from pipeline.cli import console as console_module
from pipeline.cli.main import app
from pipeline.runtime.executor import StagePlan, StageReport
from pipeline.runtime.status import UnitOutcome
from tests.cli.test_confinement import make_run

runner = CliRunner()
# Commands whose help texts this area writes (evaluate's options belong to the evaluate area).
OWN = {"demo", "submit", "rerun", "status", "query", "stats", "logs", "schemas", "preview", "export", "import-mvpd",
       "scenes generate", "scenes preview", "scenes stats", "plan preview", "plan report"}


def _commands(group: click.Group, prefix: str = "") -> list[tuple[str, click.Command]]:
    found = []
    for name, command in sorted(group.commands.items()):
        if hasattr(command, "commands"):  # a group (typer's may not be click's own Group class)
            found.extend(_commands(command, f"{prefix}{name} "))
        else:
            found.append((f"{prefix}{name}", command))
    return found


COMMANDS = _commands(typer.main.get_command(app))


def test_version_and_short_help():
    version = runner.invoke(app, ["--version"])
    assert version.exit_code == 0 and version.output.startswith("mvpd ")
    assert runner.invoke(app, ["-h"]).output == runner.invoke(app, ["--help"]).output


@pytest.mark.parametrize("name, command", COMMANDS, ids=[name for name, _ in COMMANDS])
def test_help_is_whole_with_flags_and_defaults(name, command):
    result = runner.invoke(app, [*name.split(), "-h"], terminal_width=80)
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert "…" not in result.output and not any(line.endswith("...") for line in result.output.splitlines()[1:])
    assert "<bool>" not in result.output  # flags are shown as flags
    for parameter in command.params:
        if not isinstance(parameter, click.Option) or parameter.hidden or parameter.name == "help":
            continue
        flag = parameter.opts[0]
        assert flag in text, (name, flag)
        record = " ".join(" ".join(parameter.get_help_record(click.Context(command)) or ()).split())
        if parameter.is_flag or parameter.required:
            continue
        if parameter.default is not None or name in OWN:
            assert "default" in record, (name, flag, record)


def test_command_list_shows_whole_first_paragraphs():
    text = " ".join(runner.invoke(app, ["-h"], terminal_width=80).output.split())
    for command in typer.main.get_command(app).commands.values():
        first = " ".join((command.help or "").split("\n\n")[0].split())
        assert first and first.split()[-1] in text


def test_tables_keep_their_width_in_pipes(tmp_path):
    run = make_run(tmp_path / "run")
    long_id = "unit-" + "0123456789" * 15
    result = runner.invoke(app, ["query", str(run.root), f"select '{long_id}' as id, 1 as n"], terminal_width=80)
    assert result.exit_code == 0, result.output
    assert long_id in result.output and max(len(line) for line in result.output.splitlines()) > 150


def test_progress_lines_outside_a_terminal(monkeypatch, capsys):
    monkeypatch.setattr(console_module, "PROGRESS_SECONDS", 0.05)
    units = [object()] * 4
    with console_module.stage_progress() as observer:  # pytest's captured stdout is not a terminal
        observer.on_stage_start(StagePlan("render", units, units, ["already"]))
        observer.on_unit(UnitOutcome("render", "a", "done", 1))
        observer.on_unit(UnitOutcome("render", "b", "failed", 1, "ValueError", "bad"))
        time.sleep(0.3)
        observer.on_stage_end(StageReport("render", 5, 1, [], 1.0))
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "render: 4 units to run, 1 up to date"
    ticks = [line for line in lines if line.startswith("render: 2/4 units (1 failed), ")]
    assert ticks and "units/s" in ticks[0] and "ETA" in ticks[0]
