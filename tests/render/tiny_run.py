"""A tiny planned run (plan tables written by hand) and a renderer stage that uses the in-memory room."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.config import Illumination, Job, ProceduralSource, RenderConfig, SceneSources
from pipeline.io.tables import to_table
from pipeline.plan.poses import level_camera_rotations, matrix_to_quaternion
from pipeline.render.stage import RgbdRenderer
from pipeline.runtime.executor import run_unit_locally
from pipeline.store.run_folder import RunFolder
from pipeline.scenes.scene import Scene
from tests.render.tiny_scenes import embodiment, room_scene

FRAMES = 6


class RoomRenderer(RgbdRenderer):
    """The render stage with its scene taken from tests.render.tiny_scenes instead of the `scenes` table."""

    def load_scene(self, run: RunFolder, scene_id: str) -> Scene:
        return room_scene()


def tiny_job(seed: int = 0) -> Job:
    """Two embodiments (ambient + ideal depth; 20 W spot + structured-light depth), two heights each."""
    return Job(name="tiny-render", seed=seed, scenes=SceneSources(procedural=ProceduralSource(count=1)),
               render=RenderConfig(frames_per_shard=4),
               embodiments=[embodiment(name="ambient"),
                            embodiment(name="spot", model="structured_light",
                                       light=Illumination(kind="spot", power=20.0))])


def write_plan(run: RunFolder, job: Job) -> None:
    """One floor path (walk 5 cm per frame along +z, turning 1 degree per frame) at every placement."""
    trajectories, frames = [], []
    headings = np.radians(90.0 + np.arange(FRAMES) * 1.0)  # heading 90 degrees = looking along +z
    rotations = level_camera_rotations(headings)
    quaternions = matrix_to_quaternion(rotations)
    for body in job.embodiments:
        fx, fy, cx, cy = body.sensor.intrinsics()
        for height in body.placements:
            name = f"room.{0:010d}.{round(height * 1000):010d}"
            trajectories.append({
                "embodiment": body.name, "video_name": name, "scene_id": "room", "trajectory": 0, "height_m": height,
                "frames": FRAMES, "path_length_m": 0.05 * (FRAMES - 1), "seed": 0, "width": body.sensor.width,
                "height": body.sensor.height, "fx": fx, "fy": fy, "cx": cx, "cy": cy, "near": body.sensor.near,
                "far": body.sensor.far, "waypoints": 2, "start_x": 0.0, "start_z": -1.5, "goal_x": 0.0,
                "goal_z": -1.5 + 0.05 * (FRAMES - 1)})
            for t in range(FRAMES):
                qw, qx, qy, qz = quaternions[t]
                frames.append({"embodiment": body.name, "video_name": name, "frame": t, "px": 0.0, "py": height,
                               "pz": -1.5 + 0.05 * t, "qw": qw, "qx": qx, "qy": qy, "qz": qz})
    run.commit_tables("plan", "room", {"trajectories": to_table("trajectories", trajectories),
                                        "frames": to_table("frames", frames)})


def render_tiny_run(root: Path, seed: int = 0, job: Job | None = None) -> RunFolder:
    """Create, plan (by hand) and render the tiny run at `root` (with `job`'s embodiments if given); returns the run."""
    job = job or tiny_job(seed)
    run = RunFolder.create(root, job)
    write_plan(run, job)
    stage = RoomRenderer(job)
    for unit in stage.units(run):
        run_unit_locally(stage, run, unit)
    return run
