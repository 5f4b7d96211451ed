"""The stats picture's zero-shot cluster panel: a cluster no training video shows is seen, and reads as zero."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from PIL import Image

from pipeline.io.dataset_stats import draw_cluster_histogram

RED = np.array([0xD6, 0x27, 0x28])  # the unseen clusters' colour


def cluster(training_videos: int, unseen: bool, *names: str) -> dict[str, object]:
    return {"cluster": len(names), "size": len(names), "training_videos": training_videos, "unseen": unseen,
            "example_names": list(names)}


def test_an_unseen_cluster_no_training_video_shows_is_a_hatched_stub_labelled_zero(tmp_path) -> None:
    figure = Figure(figsize=(6, 3))
    axis = figure.add_subplot()
    draw_cluster_histogram(axis, [cluster(0, True, "lamp", "vase"), cluster(0, False, "rug"), cluster(25, False, "chair")])
    figure.savefig(tmp_path / "clusters.png", dpi=90)
    unseen, seen_zero, seen = axis.patches
    assert seen.get_height() == 25 and seen.get_fill()  # a counted bar keeps its height
    assert unseen.get_hatch() == "//" and not unseen.get_fill() and unseen.get_linestyle() == "--"
    assert [text.get_text() for text in axis.texts] == ["0", "0", "25"]  # the stubs say they are zero

    box = unseen.get_window_extent()  # display pixels, y up; the PNG's rows go down
    pixels = np.asarray(Image.open(tmp_path / "clusters.png").convert("RGB")).astype(int)
    inside = pixels[pixels.shape[0] - int(box.y1) + 1:pixels.shape[0] - int(box.y0) - 1, int(box.x0) + 1:int(box.x1) - 1]
    assert box.height >= 4  # before, a bar of height 0: no pixel of it was drawn
    assert (np.abs(inside - RED).sum(axis=2) < 60).mean() > 0.05  # red hatching shows inside the stub
