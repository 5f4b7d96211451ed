"""`mvpd plan preview` on a generated house planned end to end (shard -> plan -> picture)."""

from __future__ import annotations

import cv2
import numpy as np
from typer.testing import CliRunner

from pipeline.cli.main import app
from pipeline.config import Body, Embodiment, Job, PlanConfig, ProceduralSource, SceneSources
from pipeline.plan.preview import PATH_COLOR
from pipeline.runtime.executor import run_unit_locally
from pipeline.store.run_folder import RunFolder
from pipeline.stages import make_stage


def test_preview_draws_the_paths_of_a_planned_house(tmp_path):
    job = Job(name="preview", seed=0, scenes=SceneSources(procedural=ProceduralSource(count=1, detail=0.05)),
              embodiments=[Embodiment(name="low", placements=[0.1], body=Body())],
              plan=PlanConfig(trajectories_per_scene=3, min_frames=20, max_frames=300))
    run = RunFolder.create(tmp_path / "run", job)
    for name in ("shard", "plan"):
        stage = make_stage(name, job)
        for unit in stage.units(run):
            marker = run_unit_locally(stage, run, unit)
    assert marker.info["status"] == "planned"
    out = tmp_path / "plan.png"
    result = CliRunner().invoke(app, ["plan", "preview", str(run.root), "proc-000000", "--out", str(out),
                                      "--size", "400"])
    assert result.exit_code == 0, result.output
    assert "3 paths of low" in result.output
    image = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    assert np.all(image == PATH_COLOR, axis=2).sum() > 20  # the paths are drawn

    missing = CliRunner().invoke(app, ["plan", "preview", str(run.root), "nowhere", "--out", str(out)])
    assert missing.exit_code == 2 and "no scene 'nowhere'" in missing.output
    unknown = CliRunner().invoke(app, ["plan", "preview", str(run.root), "proc-000000", "--out", str(out),
                                       "--embodiment", "tall"])
    assert unknown.exit_code == 2 and "no embodiment 'tall'" in unknown.output


def test_preview_colours_islands_apart_greys_left_out_ones_and_has_a_legend():
    from pipeline.plan.navigable import drawable_islands
    from pipeline.plan.preview import DROPPED_COLOR, GOAL_COLOR, START_COLOR, _island_palette, preview_image
    from pipeline.plan.synthetic import FURNITURE, Box, room_shell, scene_from_boxes
    from tests.plan.planning import BODY, plan_scene

    boxes = room_shell(-4.0, 4.0, 0.0, 4.0) + [Box((-0.05, 0.0, 0.0), (0.05, 2.5, 4.0)),  # two closed rooms
                                               Box((1.0, 0.0, 1.0), (3.0, 0.5, 2.6), FURNITURE)]  # a bed
    scene = scene_from_boxes("rooms-bed", boxes)
    area, _, _ = plan_scene(scene)
    drawable = drawable_islands(area, BODY.max_step, 1.0)
    assert drawable.tolist().count(True) == 2 and (~drawable).sum() == 1  # both rooms; not the bed top
    colors = _island_palette(drawable)
    assert len({tuple(c) for c in colors[drawable]}) == 2 and tuple(colors[~drawable][0]) == DROPPED_COLOR
    image = preview_image(scene, area, [np.array([[-3.0, 1.0], [-1.0, 3.0]])], size=500, drawable=drawable)
    legend = image[:, 500:]  # the key is right of the 500-pixel picture, under the categories
    for color in (START_COLOR, GOAL_COLOR, DROPPED_COLOR, *map(tuple, colors[drawable])):
        assert np.all(legend == color, axis=2).sum() > 10, f"legend lacks {color}"
