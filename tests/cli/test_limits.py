"""Bounded resources, one line each (issue 29, points 6-10): query memory, job fields that multiply work,
deep YAML, Ctrl-C during start-up, and the exit code of a driver that lost its lease."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import threading
import tomllib
from pathlib import Path

import duckdb
import pytest

from pipeline.config import ConfigError, load_embodiment, load_job
from pipeline.cli.signals import commands_handle_signals
from pipeline.store.run_folder import RunFolder
from tests.cli.test_confinement import invoke, make_run
from tests.cli.test_trust import one_line

REPO = Path(__file__).resolve().parents[2]
BIG_QUERY = "select length(list(range)::varchar) from range(150000000)"  # 6.8 GB at DuckDB's default limit
JOB = "name: t\nscenes: {procedural: {count: 1, detail: 0.05}}\nembodiments: [{name: e}]\n"
DEEP = 5000


@pytest.fixture
def run(tmp_path: Path) -> RunFolder:
    return make_run(tmp_path / "run")


def _bytes(size: str) -> float:
    """DuckDB's `current_setting('memory_limit')` text ("5.8 GiB") in bytes."""
    number, unit = re.fullmatch(r"([\d.]+) ?(\w+)", size).groups()  # type: ignore[union-attr]
    return float(number) * 1024 ** ["bytes", "KiB", "MiB", "GiB", "TiB"].index(unit)


# ---------------------------------------------------------------------------------------- point 6


def test_query_gives_duckdb_a_quarter_of_the_memory_by_default(run):
    result = invoke("query", run.root, "select current_setting('memory_limit') as m", "--format", "json")
    assert result.exit_code == 0, result.output
    ours = _bytes(json.loads(result.output)[0]["m"])
    duckdb_default = _bytes(duckdb.connect().sql("select current_setting('memory_limit')").fetchall()[0][0])  # 80 %
    assert ours == pytest.approx(duckdb_default * 25 / 80, rel=0.02)


def test_a_query_over_its_memory_limit_is_one_line_exit_1_and_spills_nothing(run, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # DuckDB would spill into ./.tmp
    started = time.monotonic()
    result = invoke("query", run.root, BIG_QUERY, "--memory-limit", "64MB")
    one_line(result, 1, "memory limit", "--memory-limit")
    assert time.monotonic() - started < 60
    assert not (tmp_path / ".tmp").exists()


def test_a_memory_limit_duckdb_cannot_read_is_one_line_exit_2(run):
    one_line(invoke("query", run.root, "select 1", "--memory-limit", "lots"), 2, "--memory-limit 'lots'", "8GB")


# ---------------------------------------------------------------------------------------- point 7


def test_a_huge_procedural_count_is_refused_at_once_in_one_line(tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text("name: t\nscenes: {procedural: {count: 100000000000}}\nembodiments: [{name: e}]\n")
    started = time.monotonic()
    # A process of its own with a timeout: the old code ran on, growing past 3.4 GB.
    done = subprocess.run([sys.executable, "-m", "pipeline.cli.main", "submit", str(job), "--run-dir",
                           str(tmp_path / "run"), "--executor", "local"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "scenes.procedural.count" in done.stderr and "10000" in done.stderr
    assert time.monotonic() - started < 60
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("fragment, field", [
    ("scenes: {procedural: {count: 20000}}", "scenes.procedural.count"),
    ("plan: {trajectories_per_scene: 5000}", "plan.trajectories_per_scene"),
    ("plan: {max_frames: 1000000}", "plan.max_frames"),
    ("plan: {min_frames: 1000000}", "plan.min_frames"),
    ("plan: {max_attempts: 1000000000}", "plan.max_attempts"),
    ("embodiments: [{name: e, sensor: {width: 8192, height: 8192}}]", "embodiments.0.sensor"),
    ("embodiments: [{name: e, placements: [HEIGHTS], body: {height: 100}}]", "embodiments.0.placements"),
    ("embodiments: [EMBODIMENTS]", "embodiments"),
    ("evaluate: {ks: [1, 100000]}", "evaluate.ks.1"),
    ("runtime: {max_retries: 1000000}", "runtime.max_retries"),
])
def test_job_fields_that_multiply_work_have_bounds_naming_the_field(tmp_path, fragment, field):
    text = (fragment.replace("HEIGHTS", ", ".join(str(0.1 + i / 100) for i in range(40)))
            .replace("EMBODIMENTS", ", ".join(f"{{name: e{i}}}" for i in range(100))))
    base = {"scenes": "scenes: {procedural: {count: 1}}", "embodiments": "embodiments: [{name: e}]"}
    key = fragment.split(":")[0]
    lines = ["name: t", *(value for name, value in base.items() if name != key), text]
    job = tmp_path / "job.yaml"
    job.write_text("\n".join(lines) + "\n")
    with pytest.raises(ConfigError) as refused:
        load_job(job)
    message = str(refused.value)
    assert "\n" not in message and message.startswith(f"{job}: {field}: "), message


def test_the_schema_says_the_bounds(tmp_path):
    schema = json.loads((REPO / "schemas" / "job.schema.json").read_text())
    procedural = schema["$defs"]["ProceduralSource"]["properties"]["count"]
    assert procedural["maximum"] == 10_000 and "10,000" in procedural["description"]
    assert schema["$defs"]["PlanConfig"]["properties"]["max_frames"]["maximum"] == 10_000


# ---------------------------------------------------------------------------------------- point 8


def deep_yaml(depth: int = DEEP) -> str:
    return "name: t\nscenes: " + "[" * depth + "]" * depth + "\nembodiments: [{name: e}]\n"


def test_a_job_nested_5000_deep_is_one_line(tmp_path):
    job = tmp_path / "job.yaml"
    job.write_text(deep_yaml())
    result = invoke("submit", job, "--run-dir", tmp_path / "run", "--executor", "local")
    one_line(result, 2, f"{job}:2: not valid YAML", "nested deeper than 50 levels")
    assert not (tmp_path / "run").exists()


def test_deep_nesting_within_the_bound_reaches_validation_and_one_beyond_it_is_refused(tmp_path):
    within, beyond = tmp_path / "within.yaml", tmp_path / "beyond.yaml"
    # The document's mapping is level 1, the scenes mapping level 2, so 48 brackets reach level 50.
    within.write_text("name: t\nscenes: {procedural: " + "[" * 48 + "]" * 48 + "}\nembodiments: [{name: e}]\n")
    beyond.write_text("name: t\nscenes: {procedural: " + "[" * 49 + "]" * 49 + "}\nembodiments: [{name: e}]\n")
    with pytest.raises(ConfigError, match="scenes.procedural: Input should be a valid dictionary"):
        load_job(within)
    with pytest.raises(ConfigError, match="nested deeper than 50"):
        load_job(beyond)


def test_a_deep_embodiment_file_a_deep_model_file_and_a_deep_run_job_are_one_line(tmp_path, run):
    embodiment = tmp_path / "robot.yaml"
    embodiment.write_text("name: r\nsensor: " + "{a: " * DEEP + "1" + "}" * DEEP + "\n")
    with pytest.raises(ConfigError, match="robot.yaml:2: not valid YAML .nested deeper"):
        load_embodiment(embodiment)
    model = tmp_path / "model.yaml"
    model.write_text("name: geometric\noptions: " + "[" * DEEP + "]" * DEEP + "\n")
    one_line(invoke("predict", run.root, "--model-file", model, "--out", tmp_path / "p"), 2, "model.yaml", "nested deeper")
    (run.root / "job.yaml").write_text("job: " + "[" * DEEP + "]" * DEEP + "\n")  # the run's own copy, damaged
    one_line(invoke("status", run.root), 2, "job.yaml", "nested deeper")


# ---------------------------------------------------------------------------------------- point 9


ENTRY_POINTS = {"python -m pipeline.cli.main": ["-m", "pipeline.cli.main"],
                "the mvpd script": ["-c", "from pipeline.cli.startup import main; main()"]}


def test_the_mvpd_script_is_the_thin_entry_point():
    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["mvpd"] == "pipeline.cli.startup:main"


@pytest.mark.parametrize("code", [130, 143, 2, 0])
def test_a_stopped_command_exits_with_its_code_after_the_exit_callbacks(tmp_path, code):
    """run_command_line: a command stopped by a signal (130 / 143) skips the interpreter's teardown (where a
    native thread still unwinding aborted the process) but not the exit callbacks (Ray's shutdown, logging);
    every other exit is Python's own."""
    marker = tmp_path / "callbacks-ran"
    script = (f"import atexit\nfrom pipeline.cli.signals import run_command_line\n"
              f"atexit.register(lambda: open({str(marker)!r}, 'w').close())\n"
              f"def app():\n    raise SystemExit({code})\nrun_command_line(app)\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == code and done.stderr == ""
    assert marker.exists()


@pytest.mark.parametrize("entry", ENTRY_POINTS)
@pytest.mark.parametrize("sent, code, words", [(signal.SIGINT, 130, "interrupted (Ctrl-C)"),
                                               (signal.SIGTERM, 143, "SIGTERM")])
def test_a_signal_at_any_moment_of_start_up_is_one_line(run, entry, sent, code, words):
    """Sent 0.15 s after start (the imports; the first ~50 ms are the interpreter's own start-up, before any
    code of ours can run), and later: while the query runs or as it ends. Each answer is the signal's exit
    code with one line, or, when the command had already finished, its result."""
    interrupted = 0
    for delay in (0.15, 0.3, 0.6, 1.0, 1.5, 2.5):
        # A shell may start children with SIGINT ignored; a user's terminal does not.
        process = subprocess.Popen([sys.executable, *ENTRY_POINTS[entry], "query", str(run.root), "select 1 as x",
                                    "--format", "csv"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        time.sleep(delay)
        process.send_signal(sent)
        stdout, stderr = process.communicate(timeout=60)
        if process.returncode == 0:  # finished before the signal
            assert stdout == "x\n1\n" and stderr == "", (delay, stderr)
            continue
        assert process.returncode == code, (delay, stderr)
        assert stderr.count("\n") == 1 and stderr.startswith("stopped: ") and words in stderr, (delay, stderr)
        interrupted += 1
    assert interrupted >= 3  # the imports alone take longer than 0.6 s


# ---------------------------------------------------------------------------------------- point 10


def test_a_driver_that_lost_its_lease_exits_1_as_the_readme_says(tmp_path, monkeypatch):
    job = tmp_path / "job.yaml"
    job.write_text(JOB)
    commit = RunFolder.commit_unit

    def taken_over_first(self: RunFolder, *args, **options):
        lock = self.root / "_state" / "lock.json"  # another driver takes the lock over, as it may once ours is stale
        lock.write_text(json.dumps({**json.loads(lock.read_text()), "owner": "elsewhere.7.0", "host": "elsewhere",
                                    "pid": 7}))
        return commit(self, *args, **options)

    monkeypatch.setattr(RunFolder, "commit_unit", taken_over_first)
    result = invoke("submit", job, "--run-dir", tmp_path / "run", "--stages", "shard", "--executor", "local")
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output
    last = result.output.strip().splitlines()[-1]
    assert last.startswith("error: ") and "now held by pid 7 on elsewhere" in last, result.output
    readme = (REPO / "README.md").read_text()
    assert "1 some unit failed or the command was stopped by its storage" in readme and "lost run lock lease" in readme


def test_a_signal_while_duckdb_runs_on_the_main_thread_is_a_keyboard_interrupt():
    """DuckDB ends a statement that Ctrl-C interrupts on the main thread with RuntimeError('Query interrupted') (CI
    caught `mvpd query` printing that stack dump when the signal came as the result was converted); while a command
    runs, the CLI's signal handling raises KeyboardInterrupt instead, which it ends in one line (exit 130)."""
    connection = duckdb.connect()
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt), commands_handle_signals(lambda: None):
            connection.execute("select count(*) from range(3000000000) where range % 7 = 3").fetchall()  # ~15 s whole
    finally:
        timer.cancel()
