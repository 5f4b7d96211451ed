"""`mvpd predict` and `mvpd report`: a model's masks for a run's videos, and the paper's tables for a run
(thin: parse, delegate to `pipeline.models`, print)."""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path
from typing import Annotated, Optional

import typer

from pipeline.cli.console import EXIT_FAILED, console, fail, stage_progress
from pipeline.cli.out_paths import check_out_location, out_folder
from pipeline.config import ConfigError
from pipeline.store.lock import RunLockedError
from pipeline.store.run_folder import RunFolder, RunFolderError


def _input_errors() -> tuple[type[Exception], ...]:
    from pipeline.evaluate.errors import EvaluationInputError
    from pipeline.models.predict import PredictionInputError
    from pipeline.models.segmenter import ModelError
    from pipeline.split.selection import UnknownSplitError

    return (ModelError, PredictionInputError, EvaluationInputError, ConfigError, RunFolderError, RunLockedError,
            UnknownSplitError)


def split_videos(run: RunFolder, split: str | None) -> list[str] | None:
    """Video names of `split` in the run (from its split stage), else None."""
    if split is None:
        return None
    from pipeline.split.selection import accepted_videos

    accepted = accepted_videos(run, split)
    if accepted is None:
        console.print(f"[yellow]the run has no split: predicting every video, not {split!r}[/]")
        return None
    return sorted({name for _, name in accepted})


DEMO_MODELS = ("geometric", "geometric+sp")


def demo_model_report(run: RunFolder, address: str | None) -> None:
    """The demo's last step: `geometric` with and without self-prompting, reported into RUN/report."""
    from pipeline.models.report import ReportError, write_model_report

    try:
        with stage_progress() as observer:
            path = write_model_report(run, DEMO_MODELS, address=address, observer=observer)
    except _input_errors() as error:
        fail(str(error))
    except ReportError as error:
        fail(str(error), EXIT_FAILED)
    console.print(f"[bold]models:[/] {path} (geometric with and without FastSPAM self-prompting)")


def register(app: typer.Typer) -> None:
    """Add `mvpd predict` and `mvpd report` to the app."""

    @app.command("predict")
    def predict(
        run: Annotated[Path, typer.Argument(help="run folder whose rendered videos are segmented")],
        out: Annotated[Path, typer.Option("--out", help="prediction folder (a small run folder of its own)")],
        model: Annotated[Optional[str], typer.Option("--model", help="segmenter: geometric, oracle, ultralytics, sam")] = None,
        model_file: Annotated[Optional[Path], typer.Option("--model-file", help="YAML: name, options, self_prompting, fastspam")] = None,
        self_prompting: Annotated[bool, typer.Option("--self-prompting", help="wrap the segmenter in FastSPAM")] = False,
        split: Annotated[Optional[str], typer.Option("--split", help="predict only this split's videos (when the run has a split)")] = None,
        embodiment: Annotated[Optional[str], typer.Option("--embodiment", help="the embodiment whose videos are predicted")] = None,
        all_videos: Annotated[bool, typer.Option("--all", help="predict every video again, even those already done")] = False,
        address: Annotated[Optional[str], typer.Option(help="Ray cluster address [default: a local Ray]")] = None,
    ) -> None:
        """Per-frame masks of a model (optionally with FastSPAM self-prompting), one Ray task per video."""
        from pipeline.models.predict import NO_SPLIT, ModelConfig, load_model_file, predict_run

        if (model is None) == (model_file is None):
            fail("give --model NAME or --model-file FILE.yaml (one of them)")
        try:
            config = load_model_file(model_file) if model_file is not None else ModelConfig(name=model or "")
            if self_prompting:
                config = config.model_copy(update={"self_prompting": True})
            source = RunFolder.open(run)
            videos = split_videos(source, split)
            with stage_progress() as observer:
                report = predict_run(source, check_out_location(out), config, embodiment, videos,
                                     split if videos is not None else NO_SPLIT, force=all_videos, address=address,
                                     on_start=observer.on_stage_start, on_unit=observer.on_unit)
                if observer.on_stage_end is not None:
                    observer.on_stage_end(report)
        except _input_errors() as error:
            fail(str(error))
        console.print(f"predictions of {config.spec} in {out}; score them: mvpd evaluate {run} --pred {out}")
        if report.failed:
            raise typer.Exit(EXIT_FAILED)

    @app.command("report")
    def report(
        run: Annotated[Path, typer.Argument(help="run folder")],
        models: Annotated[str, typer.Option("--models", help="comma-separated model specs, e.g. geometric,geometric+sp (+sp = FastSPAM)")] = "geometric,geometric+sp",
        out: Annotated[Optional[Path], typer.Option("--out", help="report folder [default: RUN/report]")] = None,
        embodiment: Annotated[Optional[str], typer.Option("--embodiment", help="embodiment [default: the job's first]")] = None,
        split: Annotated[Optional[str], typer.Option("--split", help="report on this split's videos (when the run has a split)")] = None,
        address: Annotated[Optional[str], typer.Option(help="Ray cluster address [default: a local Ray]")] = None,
    ) -> None:
        """Predict and evaluate each model as needed, then write report.md and PNG plots of the paper's tables."""
        from pipeline.models.predict import NO_SPLIT
        from pipeline.models.report import ReportError, write_model_report

        specs = [m.strip() for m in models.split(",") if m.strip()]
        try:
            opened = RunFolder.open(run)
            videos = split_videos(opened, split)
            with out_folder(out, "mvpd report") if out is not None else nullcontext(None) as target, \
                    stage_progress() as observer:
                path = write_model_report(opened, specs, target, embodiment, videos,
                                          split if videos is not None else NO_SPLIT, address=address, observer=observer)
        except _input_errors() as error:
            fail(str(error))
        except ReportError as error:
            fail(str(error), EXIT_FAILED)
        console.print(f"[bold]report:[/] {path}")
