"""Look at a rendered video: an animated GIF (or MP4) and a PNG contact sheet, RGB | depth | panoptic per row.

Depth is colour-mapped (cv2 TURBO) over one range for the whole video (2nd-98th percentile of valid depth),
so colours compare across frames; 0 (no return) is black. Panoptic ids get a colour from a hash of the id,
the same in every frame and every video; void is black.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from PIL import Image

from pipeline.io.reader import LoadedVideo
from pipeline.store.names import replaced

GAP = 2  # pixels of black between panels and rows


@dataclass(frozen=True)
class PreviewFiles:
    """Paths written by `write_preview`."""

    animation: Path
    contact_sheet: Path


def id_colors(panoptic: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 colour per panoptic id: a fixed integer hash of the id (void 0 is black)."""
    ids = panoptic.astype(np.uint64)
    # Multiplicative hash (Knuth) then xor-shift: neighbouring ids get unrelated colours.
    h = (ids * np.uint64(2654435761)) & np.uint64(0xFFFFFFFF)
    h ^= h >> np.uint64(15)
    h = (h * np.uint64(2246822519)) & np.uint64(0xFFFFFFFF)
    rgb = np.stack([(h >> np.uint64(s)) & np.uint64(255) for s in (0, 8, 16)], axis=-1).astype(np.uint8)
    rgb = rgb // 2 + 64  # mid-range colours stay visible against black void
    rgb[panoptic == 0] = 0
    return rgb


def depth_range(depth: np.ndarray) -> tuple[float, float]:
    """(low, high) millimetres used for the colour map: 2nd and 98th percentile of valid depth."""
    valid = depth[depth > 0]
    if valid.size == 0:
        return 0.0, 1.0
    low, high = np.percentile(valid, [2, 98])
    return float(low), float(max(high, low + 1.0))


def depth_colors(depth: np.ndarray, low: float, high: float) -> np.ndarray:
    """(H, W, 3) uint8 RGB colour map of one depth frame (mm); no return (0) is black."""
    scaled = np.clip((depth.astype(np.float32) - low) / (high - low), 0.0, 1.0)
    bgr = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    rgb = bgr[..., ::-1].copy()
    rgb[depth == 0] = 0
    return rgb


def frame_panel(rgb: np.ndarray, depth: np.ndarray, panoptic: np.ndarray, depth_limits: tuple[float, float],
                label: str = "") -> np.ndarray:
    """One row: RGB | depth | panoptic, side by side, with an optional label drawn on the RGB panel."""
    height = rgb.shape[0]
    gap = np.zeros((height, GAP, 3), np.uint8)
    row = np.concatenate([rgb, gap, depth_colors(depth, *depth_limits), gap, id_colors(panoptic)], axis=1)
    if label:
        scale = max(height / 480.0, 0.3)
        cv2.putText(row, label, (4, int(18 * scale) + 2), cv2.FONT_HERSHEY_SIMPLEX, 0.6 * scale, (255, 255, 255),
                    max(1, int(2 * scale)), cv2.LINE_AA)
    return row


def sheet_frames(frames: int, rows: int) -> list[int]:
    """`rows` frame indices spread evenly over the video (first and last included)."""
    if frames <= rows:
        return list(range(frames))
    return sorted({int(round(i)) for i in np.linspace(0, frames - 1, rows)})


def write_preview(video: LoadedVideo, out_dir: Path, rows: int = 6, animation: Literal["gif", "mp4"] = "gif",
                  max_animation_frames: int = 300, fps: float = 10.0) -> PreviewFiles:
    """Write `<out_dir>/<video>.gif` (or .mp4) and `<out_dir>/<video>.png`; returns their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    limits = depth_range(np.asarray(video.depth[:: max(1, video.frames // 32)]))
    sheet_rows = []
    for index in sheet_frames(video.frames, rows):
        frame = video.frame(index)
        sheet_rows.append(frame_panel(frame["rgb"], frame["depth"], frame["panoptic"], limits, f"t={index}"))
    sheet = np.concatenate([np.pad(r, ((0, GAP), (0, 0), (0, 0))) for r in sheet_rows], axis=0)[:-GAP]
    sheet_path = out_dir / f"{video.name}.png"
    with replaced(sheet_path) as temporary:  # a new file: never written into one it does not own (a hard link)
        Image.fromarray(sheet).save(temporary, format="PNG", optimize=True)
    step = max(1, -(-video.frames // max_animation_frames))
    panels = [frame_panel(f["rgb"], f["depth"], f["panoptic"], limits)
              for f in (video.frame(t) for t in range(0, video.frames, step))]
    animation_path = out_dir / f"{video.name}.{animation}"
    with replaced(animation_path) as temporary:
        if animation == "gif":
            images = [Image.fromarray(p) for p in panels]
            images[0].save(temporary, format="GIF", save_all=True, append_images=images[1:], duration=int(1000 / fps),
                           loop=0)
        else:
            _write_mp4(temporary, panels, fps)
    return PreviewFiles(animation_path, sheet_path)


def _write_mp4(path: Path, panels: list[np.ndarray], fps: float) -> None:
    height, width = panels[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    if not writer.isOpened():
        raise OSError(f"{path}: OpenCV cannot write MP4 here (no mp4v encoder); use --format gif")
    for panel in panels:
        writer.write(panel[..., ::-1])
    writer.release()
