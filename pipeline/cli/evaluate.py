"""`mvpd evaluate`: VSQ of a model's predictions on a run of ours or on an MVPd split (thin: parse,
delegate to `pipeline.evaluate.api`, print)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.markup import escape

from pipeline.cli.console import EXIT_BAD_INPUT, EXIT_FAILED, console, fail, print_table, stage_progress
from pipeline.cli.out_paths import check_out_file, check_out_location
from pipeline.cli.run_commands import EXECUTOR_HELP, ExecutorChoice
from pipeline.config import ConfigError
from pipeline.runtime.executor import StageOrderError
from pipeline.store.lock import RunLockedError
from pipeline.store.run_folder import RunFolder, RunFolderError

INPUT_ERROR_TYPES = {"EvaluationInputError", "PredictionError", "MissingPredictionError", "GroundTruthError"}


def register(app: typer.Typer) -> None:
    """Add `mvpd evaluate` to the app."""

    @app.command("evaluate")
    def evaluate(
        run: Annotated[Optional[Path], typer.Argument(help="run folder whose rendered videos are the ground truth")] = None,
        pred: Annotated[Path, typer.Option("--pred", help="predictions: <pred>/panomasksRLE/<video>/<frame>.json (or .pt), or <pred>/<video>.zarr ids")] = ...,  # type: ignore[assignment]
        gt_mvpd: Annotated[Optional[Path], typer.Option("--gt-mvpd", help="MVPd release root holding <split>/panoptic_<split>.json")] = None,
        split: Annotated[Optional[str], typer.Option("--split", help="MVPd split to evaluate (with --gt-mvpd); for a run with a split stage, its split whose accepted videos are scored [default: test]")] = None,
        videos: Annotated[Optional[str], typer.Option("--videos", help="score only these videos: names or globs, comma-separated (predictions needed only for them)")] = None,
        out: Annotated[Optional[Path], typer.Option("--out", help="write the result JSON here (required with --gt-mvpd)")] = None,
        work: Annotated[Optional[Path], typer.Option("--work", help="evaluation run folder for --gt-mvpd [default: <out>.run]")] = None,
        embodiment: Annotated[Optional[str], typer.Option("--embodiment", help="runs: evaluate this embodiment's videos")] = None,
        allow_missing: Annotated[bool, typer.Option("--allow-missing", help="count a missing prediction frame as empty (reported)")] = False,
        k: Annotated[Optional[list[int]], typer.Option("--k", help="prefix length, repeatable [default: 1 5 10 15]")] = None,
        window: Annotated[Optional[int], typer.Option(help="window length [default: 15]")] = None,
        stride: Annotated[Optional[int], typer.Option(help="frames between window starts [default: 15]")] = None,
        min_area_fraction: Annotated[Optional[float], typer.Option(help="ground-truth ids below this fraction become void [default: 0.001]")] = None,
        subsample: Annotated[Optional[int], typer.Option(help="keep every n-th row and column [default: 2]")] = None,
        all_videos: Annotated[bool, typer.Option("--all", help="evaluate every video again, even those already done")] = False,
        address: Annotated[Optional[str], typer.Option(help="Ray cluster address [default: a local Ray]")] = None,
        executor: Annotated[ExecutorChoice, typer.Option(help=EXECUTOR_HELP)] = ExecutorChoice.auto,
    ) -> None:
        """VSQ of per-frame (or tracked) predictions, one Ray task per video; prints a table, writes JSON."""
        from pipeline.evaluate.api import evaluate_mvpd, evaluate_run
        from pipeline.evaluate.errors import EvaluationInputError
        from pipeline.evaluate.report import summary_table, write_json
        from pipeline.evaluate.subset import parse_video_patterns
        from pipeline.evaluate.vsq import ProtocolError
        from pipeline.split.selection import has_split

        if (run is None) == (gt_mvpd is None):
            fail("give either a RUN folder or --gt-mvpd ROOT --split SPLIT (not both)")
        if gt_mvpd is not None and (split is None or out is None):
            fail("--gt-mvpd needs --split SPLIT and --out FILE.json")
        if out is not None:
            out = check_out_file(out)
        if work is not None:
            work = check_out_location(work, "--work")
        overrides = {"ks": sorted(set(k)) if k else None, "window": window, "stride": stride,
                     "min_area_fraction": min_area_fraction, "subsample": subsample}
        try:
            with stage_progress() as observer:
                common = dict(allow_missing=allow_missing, overrides=overrides, force=all_videos, address=address,
                              on_start=observer.on_stage_start, on_unit=observer.on_unit,
                              videos=parse_video_patterns(videos), executor=executor.value)
                if gt_mvpd is not None:
                    assert split is not None and out is not None
                    result = evaluate_mvpd(gt_mvpd, split, pred, RunFolder(work or out.with_suffix(".run")), **common)  # type: ignore[arg-type]
                    result.split = split
                else:
                    assert run is not None
                    opened = RunFolder.open(run)
                    if not has_split(opened):
                        console.print(f"{run}: no split stage in this run; scoring every video (zero-shot bucket empty)")
                    result = evaluate_run(opened, pred, embodiment, split=split, **common)  # type: ignore[arg-type]
        except (EvaluationInputError, ProtocolError, ConfigError, RunFolderError, RunLockedError, StageOrderError) as error:
            fail(str(error))
        for video, info in result.videos.items():
            if info["missing_frames"]:
                console.print(f"[yellow]{video}: {info['missing_frames']} prediction frames missing, counted as empty[/]")
        for outcome in result.failed:
            console.print(f"[red]x[/] {outcome.unit}: {outcome.error_type}: {escape(outcome.message)}", soft_wrap=True)
        print_table(summary_table(result))
        if out is not None:
            write_json(result, out)
            console.print(f"wrote {out}")
        if result.failed:
            input_only = all(o.error_type in INPUT_ERROR_TYPES for o in result.failed)
            raise typer.Exit(EXIT_BAD_INPUT if input_only else EXIT_FAILED)
