"""The dataset card (`README.md`) of a Hugging Face export: the Hub's YAML front matter and the prose.

The front matter is made by `datasets` and `huggingface_hub` themselves (`DatasetInfosDict.to_dataset_card_data`,
`DatasetCardData.to_yaml`), the very path `push_to_hub` takes, so `load_dataset(DIR)` reads back the feature
types, the splits' data files and their row counts (which it verifies) from it. Nothing in the card depends
on the time or the machine: the same run gives the same card.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from pipeline.config import Embodiment, Job

if TYPE_CHECKING:
    import datasets

    from pipeline.io.huggingface.shards import SplitShards

DATA = "data"
JOB_COPY = "mvpd_job.yaml"  # not job.yaml: a folder holding job.yaml is taken for a run folder

# What applies to the frames rendered from each scene source (the renders are derived works of the scans).
SOURCE_LICENCES = {
    "procedural": "generated houses (mvpd-pipeline's procedural scenes, MIT): no third-party scan",
    "hm3dsem": "HM3D / HM3DSem scans: the Matterport End User License Agreement for Academic Use of Model Data "
               "(https://matterport.com/matterport-end-user-license-agreement-academic-use-model-data)",
    "matterport3d": "Matterport3D scans: the Matterport3D Terms of Use (non-commercial academic use)",
    "scannet": "ScanNet / ScanNet++ scans: their Terms of Use (non-commercial research)",
    "replica": "Replica scans: the Replica Dataset Research Terms (https://github.com/facebookresearch/Replica-Dataset)",
    "meshes": "your own meshes: whatever licence they carry",
    "mvpd": "an imported MVPd release: MVPd's terms, which follow HM3DSem's (Matterport's academic licence)",
}

MVPD_BIBTEX = """@article{opipari2024mvpd,
  title   = {Configurable Embodied Data Generation for Class-Agnostic {RGB-D} Video Segmentation},
  author  = {Opipari, Anthony and Krishnan, Aravindhan K. and Gayaka, Shreekant and Sun, Min and
             Kuo, Cheng-Hao and Sen, Arnab and Jenkins, Odest Chadwicke},
  journal = {IEEE Robotics and Automation Letters},
  year    = {2024},
  eprint  = {2410.12995},
  archivePrefix = {arXiv}
}"""


@dataclass
class SplitFacts:
    """One exported split: its videos and frames (all, and those the split stage accepted) and shards."""

    videos: int
    accepted_videos: int | None
    frames: int
    shards: "SplitShards"


@dataclass
class CardFacts:
    """Everything the card says, gathered by the export."""

    job: Job
    job_hash: str
    code_versions: list[str]
    exporter_version: str
    features: "datasets.Features"
    splits: dict[str, SplitFacts]
    has_split_stage: bool
    height: int
    width: int
    sources: list[str] = field(default_factory=list)


def card_text(facts: CardFacts) -> str:
    """The whole `README.md`: front matter, then the prose."""
    return f"---\n{front_matter(facts)}---\n\n{prose(facts)}"


def front_matter(facts: CardFacts) -> str:
    """The YAML between the `---` lines (ends with a newline)."""
    from datasets import DatasetInfo, SplitDict, SplitInfo
    from datasets.info import DatasetInfosDict
    from huggingface_hub import DatasetCardData

    frames = sum(split.frames for split in facts.splits.values())
    card = DatasetCardData(
        license="other", license_name="source-scans", license_link="LICENSE.md",
        task_categories=["image-segmentation", "depth-estimation", "mask-generation"],
        tags=["rgb-d", "video", "panoptic-segmentation", "video-segmentation", "class-agnostic", "embodied",
              "synthetic", "mvpd"],
        size_categories=[_size_category(frames)], pretty_name=f"{facts.job.name} (mvpd-pipeline RGB-D videos)",
        configs=[{"config_name": "default", "data_files": [
            {"split": name, "path": f"{DATA}/{name}-*.parquet"} for name in facts.splits]}])
    splits = SplitDict()
    for name, split in facts.splits.items():
        splits.add(SplitInfo(name=name, num_bytes=split.shards.arrow_bytes, num_examples=split.shards.rows))
    info = DatasetInfo(features=facts.features, splits=splits,
                       download_size=sum(s.shards.file_bytes for s in facts.splits.values()),
                       dataset_size=sum(s.shards.arrow_bytes for s in facts.splits.values()))
    DatasetInfosDict({"default": info}).to_dataset_card_data(card)
    return card.to_yaml() + "\n"


LICENCE_FILE = "LICENSE.md"


def licence_notice(facts: CardFacts) -> str:
    """`LICENSE.md`: which licences apply to these frames (those of the scans they were rendered from)."""
    lines = [f"- {SOURCE_LICENCES[source]}" for source in facts.sources]
    return ("The frames of this dataset were rendered from 3D scans; the licences of those scans apply to "
            "them:\n\n" + "\n".join(lines) + "\n\nThe code that rendered them (mvpd-pipeline) is MIT-licensed.\n")


def prose(facts: CardFacts) -> str:
    """The card's Markdown body."""
    job = facts.job
    split_rows = "\n".join(
        f"| {name} | {split.videos} | {'-' if split.accepted_videos is None else split.accepted_videos} | "
        f"{split.frames} | {len(split.shards.files)} |" for name, split in facts.splits.items())
    embodiment_rows = "\n".join(_embodiment_row(e) for e in job.embodiments)
    versions = ", ".join(f"`{v}`" for v in facts.code_versions) or "(not recorded)"
    sources = "\n".join(f"- {SOURCE_LICENCES[source]}" for source in facts.sources)
    flags = ("the split stage's flags" if facts.has_split_stage else
             "null: the run had no split stage, so no video was screened")
    return f"""# {job.name}: RGB-D videos with panoptic labels, per robot embodiment

Class-agnostic RGB-D video segmentation data in the manner of MVPd (Opipari et al., RA-L 2024): camera
trajectories through buildings, each rendered once per **embodiment** (camera height, camera model, light)
into colour, depth and panoptic videos. Generated by mvpd-pipeline (a reimplementation of MVPd's data
generation) from the job file `{JOB_COPY}` beside this card.

**One row per frame** (not per clip), in video order (videos sorted by embodiment and name, frames in time
order), so any clip is a run of consecutive rows with one `video_name`. {facts.width}x{facts.height} pixels.

| split | videos | accepted videos | frames (rows) | shards |
| --- | --- | --- | --- | --- |
{split_rows}

## Use

```python
from datasets import load_dataset

ds = load_dataset("path/to/this/folder", split="train").with_format("numpy")   # or streaming=True
row = ds[0]
rgb, depth, panoptic = row["rgb"], row["depth"], row["panoptic"]   # (H, W, 3) uint8, (H, W) uint16 mm, (H, W) ids
training = ds.filter(lambda accepted: accepted, input_columns="accepted")         # MVPd's loader's videos
```

Without `.with_format("numpy")`, `rgb` and `depth` decode as PIL images (`np.asarray` gives the arrays;
depth is mode `I;16`) and `panoptic` and `pose` as nested lists (exact, but slow for pixels). The numpy
format widens integers to int64 (the ids are unchanged) and narrows floats to float32: read `pose` without
it for float64, and `ds.with_format("arrow")["panoptic"]` for the stored uint32.

## Columns

| column | type | meaning |
| --- | --- | --- |
| `video_name` | string | `<scene_id>.<trajectory:010d>.<camera height mm:010d>`; the same trajectory at two heights is one floor path |
| `frame` | int32 | frame index in the video, from 0 |
| `embodiment` | string | embodiment name (see below) |
| `scene_id` | string | scene the video was rendered in |
| `camera_height_m` | float64 | camera height above the floor, metres |
| `illumination` | string | `ambient` or `spot-<watts>W` |
| `rgb` | Image (PNG) | colour, uint8 RGB, exactly as the run stores it (lossless) |
| `depth` | Image (16-bit PNG) | planar depth along the optical axis, uint16 millimetres; 0 = no hit or beyond the far clip |
| `panoptic` | Array2D uint32 | object id per pixel, 0 = void; an object keeps its id over the video; (scene_id, id) names it across videos |
| `pose` | Array2D float64 (4, 4) | camera-to-world, OpenCV camera axes (x right, y down, z forward), world +Y up, metres |
| `intrinsics` | struct | `fx`, `fy`, `cx`, `cy` in pixels (pixel centres at u + 0.5), `width`, `height` |
| `object_ids` | list uint32 | the objects the video shows |
| `object_categories` | list int32 | their mpcat40 index, in the same order (0 = unmapped; 1 wall, 2 floor, 17 ceiling are stuff) |
| `zero_shot_object_ids` | list uint32 | those of them in an unseen (zero-shot) category: val/test score them in VSQ's zero-shot bucket |
| `empty` | bool | the video has a frame more than half void (MVPd's empty filter) |
| `zero_shot_rejected` | bool | train only: the video shows an unseen object (MVPd's zero-shot filter) |
| `accepted` | bool | neither: the videos MVPd's loader trains and evaluates on |

Every video of each split is exported, rejected ones too: the last three columns are {flags}.

## Embodiments

MVPd renders every trajectory with a tall camera (1.0 m above the floor, a person's or a tall robot's
eye) and a short one (0.1 m, a small floor robot), under ambient light (each surface's texture colour,
no light source) or a spot light mounted on the camera. This job's embodiments:

| embodiment | camera | depth sensor | heights | light |
| --- | --- | --- | --- | --- |
{embodiment_rows}

## How it was generated

Scenes were sharded, navigable paths planned, frames ray-cast (colour, depth, panoptic ids), and videos split
by scene into train / val / test with MVPd's empty-video and zero-shot filters, as the job says.

- job: `{job.name}`, job hash `{facts.job_hash}`; the resolved job (every default filled in) is `{JOB_COPY}`
- code version the run recorded (package version + hash of its sources): {versions}
- exported by mvpd-pipeline `{facts.exporter_version}` with `mvpd export RUN --hf DIR`

## Licence

The frames are renders of 3D scans, so the scans' licences apply to this dataset (`LICENSE.md`):

{sources}

## Citation

MVPd, whose data design this follows:

```bibtex
{MVPD_BIBTEX}
```
"""


def _embodiment_row(embodiment: Embodiment) -> str:
    sensor, light = embodiment.sensor, embodiment.illumination
    heights = ", ".join(f"{h:g} m" + (" (tall)" if h >= 1.0 else " (short)" if h <= 0.1 else "")
                        for h in embodiment.placements)
    fov = f"{sensor.hfov:g} deg horizontal" if sensor.hfov is not None else f"fx {sensor.fx:g} px"
    lit = "ambient (texture colour, no light)" if light.kind == "ambient" else f"spot on the camera, {light.power:g} W"
    return f"| {embodiment.name} | {sensor.width}x{sensor.height}, {fov} | {sensor.model} | {heights} | {lit} |"


def _size_category(frames: int) -> str:
    """The Hub's size bucket for a number of rows."""
    bounds = [(1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"), (1_000_000, "100K<n<1M"),
              (10_000_000, "1M<n<10M")]
    return next((label for bound, label in bounds if frames < bound), "10M<n<100M")
