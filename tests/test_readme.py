"""Every command of the README's usage section runs as written, on a demo-shaped run.

The commands are read from the section's code blocks (bash: `mvpd ...` lines; sql: each statement
through `mvpd query`; python: the block itself), so commands other people add are tested too.
`runs/demo` becomes the session's demo-shaped run (tests/demo_run.py); optional `[...]` parts are left
out; relative outputs land in a scratch folder. Commands that need what a test cannot have are listed
in SKIPPED with the reason; a SKIPPED entry that matches no README command fails, so the list stays true.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from tests.demo_run import demo_shaped_run

README = Path(__file__).resolve().parents[1] / "README.md"
SECTION = "## Using it"
DEMO_RUN = "runs/demo"
# Command prefix (after `mvpd `) -> why the test does not run it.
SKIPPED = {
    "demo": "runs the full demo job (minutes on 2 cores); the session builds a demo-shaped run instead "
            "with the same embodiments, scene ids and video names (tests/demo_run.py)",
    "submit jobs/mvpd.yaml": "the full-scale job reads HM3DSem under /data and writes to /data/runs",
    f"evaluate {DEMO_RUN} --pred predictions/": "needs a model's predictions folder (predictions/); "
                                                "tests/evaluate scores generated predictions through the same command",
    "evaluate --gt-mvpd /data/MVPd": "needs an MVPd release under /data/MVPd",
    "import-mvpd /data/MVPd": "needs an MVPd release under /data/MVPd",
}


def usage_blocks() -> list[tuple[str, str]]:
    """(language, body) of every fenced code block of the usage section."""
    text = README.read_text(encoding="utf-8")
    start = text.index(SECTION)
    end = text.find("\n## ", start + len(SECTION))
    section = text[start: end if end > 0 else len(text)]
    return re.findall(r"```(\w*)\n(.*?)```", section, flags=re.S)


def readme_commands() -> list[tuple[str, str]]:
    """(kind, text) per command: ("mvpd", argument string), ("sql", statement) or ("python", block)."""
    commands: list[tuple[str, str]] = []
    for language, body in usage_blocks():
        if language == "bash":
            for line in body.replace("\\\n", " ").splitlines():
                words = shlex.split(line, comments=True)
                if words and words[0] == "mvpd":
                    commands.append(("mvpd", line.split("#")[0].strip()[len("mvpd"):].strip()))
        elif language == "sql":
            commands += [("sql", s.strip()) for s in body.split(";") if s.strip()]
        elif language == "python":
            commands.append(("python", body))
    return commands


def _skip_reason(arguments: str) -> str | None:
    return next((reason for prefix, reason in SKIPPED.items() if arguments.startswith(prefix)), None)


def test_the_usage_section_has_commands_and_every_skip_names_one() -> None:
    commands = [text for kind, text in readme_commands() if kind == "mvpd"]
    assert len(commands) >= 15
    unmatched = [prefix for prefix in SKIPPED if not any(c.startswith(prefix) for c in commands)]
    assert not unmatched, f"SKIPPED entries that match no README command: {unmatched}"


@pytest.fixture(scope="module")
def demo_run(ray_session, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return demo_shaped_run(tmp_path_factory)


@pytest.fixture(scope="module")
def scratch(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One working folder for all commands, in README order (later commands read earlier outputs)."""
    return tmp_path_factory.mktemp("readme")


def _arguments(text: str, run: Path, scratch: Path) -> list[str]:
    text = re.sub(r"\s*\[[^\]]*\]", "", text)  # optional parts, e.g. [--all]
    words = [str(run) if w == DEMO_RUN else w for w in shlex.split(text)]
    if "<unit-id>" in words:
        words[words.index("<unit-id>")] = sorted((run / "logs" / "render").glob("*.log"))[0].stem
    if words == ["schemas"]:  # it writes into the repository's schemas/ by default
        words += ["--out", str(scratch / "schemas")]
    return words


@pytest.mark.parametrize("kind,text", readme_commands(), ids=lambda value: value[:70])
def test_readme_command_runs(kind: str, text: str, demo_run: Path, scratch: Path,
                             monkeypatch: pytest.MonkeyPatch) -> None:
    from pipeline.cli.main import app

    if kind == "mvpd" and (reason := _skip_reason(text)):
        pytest.skip(reason)
    monkeypatch.chdir(scratch)
    if kind == "python":
        exec(compile(text.replace(f'"{DEMO_RUN}"', repr(str(demo_run))), str(README), "exec"), {})
        return
    arguments = _arguments(text, demo_run, scratch) if kind == "mvpd" else ["query", str(demo_run), text]
    result = CliRunner().invoke(app, arguments)
    assert result.exit_code == 0, f"mvpd {' '.join(arguments)}\n{result.output}"
