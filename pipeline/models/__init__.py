"""Image segmenters, FastSPAM self-prompting and the `predict` stage."""
