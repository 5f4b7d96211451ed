"""VSQ evaluation, numerically identical to the published MVPd evaluator and ~100x+ faster.

    vsq.py           the metric on arrays: protocol knobs, per-video counts, pooled summary
    linking.py       Dice-Hungarian matching and tube linking (published tie-breaking)
    frames.py        per-frame arrays: filtered/subsampled ground truth, atom partitions of masks
    rle.py           COCO RLE -> subsampled runs without decoding full-resolution masks
    ground_truth.py  an MVPd-layout split folder, or the rendered videos of a run
    predictions.py   per-frame RLE JSON / .pt files, or Zarr id arrays of a tracker
    stage.py         the `evaluate` stage: one unit (Ray task) per video -> `metrics/`
    api.py           evaluate a run or an MVPd split through the runtime
    report.py        metrics table -> JSON (published layout) and a rich table
"""
