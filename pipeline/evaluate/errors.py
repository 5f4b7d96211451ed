"""Error types of the evaluate area: each message is one line naming the file (or field) and the fix."""

from __future__ import annotations


class EvaluationInputError(ValueError):
    """Unusable evaluation input (ground truth or predictions); the message names the file and the fix."""


class PredictionError(EvaluationInputError):
    """A prediction file or folder that cannot be used: missing, wrong mask size, corrupt RLE."""


class MissingPredictionError(PredictionError):
    """A video or a frame has no prediction file (`--allow-missing` turns missing frames into empty ones)."""


class GroundTruthError(EvaluationInputError):
    """A ground-truth folder or file that cannot be used (no `panoptic_<split>.json`, unreadable PNG, ...)."""
