"""The split: train / val / test by scene, the empty-video filter and the zero-shot subset (MVPd's)."""
