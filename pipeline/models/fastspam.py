"""FastSPAM: self-prompting through 3D around any "everything" segmenter (the authors'
`evaluate_selfprompting_fix` behaviour, re-implemented on our camera conventions).

Per video, for each frame t (`FastSpam.segment`):
1. the wrapped segmenter's everything-masks of frame t (empty masks dropped); `point_prompt(p)` is
   the union of every everything-mask containing pixel p;
2. memory from frame t-1: one prompt pixel per previous output mask, its centroid (coordinates
   truncated to integers, as the authors' `int()`), or, when that pixel is outside the mask, a
   pixel of the mask drawn with the video's seeded generator;
3. each prompt is unprojected with frame t-1's depth, intrinsics and pose and projected into frame t
   with its pose (`pipeline.render.camera`); prompts leaving the image or landing behind the camera
   are dropped, and so are prompts on pixels without depth (they have no 3D point);
4. for each surviving prompt, in the order of the previous outputs (largest first): its
   `point_prompt` mask is OR-ed into the output mask of highest IoU when that IoU >= `merge_iou`,
   else added as a new output mask;
5. new objects: every everything-mask (largest first) whose intersection with the union of the
   outputs of step 4, divided by its own area, is < `coverage` gives a prompt (its centroid, or a
   drawn pixel), merged by the same rule;
6. empty masks are dropped and the outputs sorted by area, largest first (ties keep their order);
7. with no prompts (first frame, or all lost) the output is the everything-masks sorted by area.
The output has no ids: the evaluator links tubes, as for any per-frame model.

Speed: every mask here is a union of everything-masks, so masks are handled as sets of *atoms*
(pixels covered by exactly the same everything-masks); IoU, coverage and centroids are small vector
products over atom statistics instead of passes over full-resolution masks.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from pipeline.models.segmenter import FrameInput, ModelError, Segmenter, parse_options
from pipeline.render.camera import pixels_inside, project, unproject


class FastSpamOptions(BaseModel):
    """FastSPAM's thresholds; the defaults are the paper's (both 0.9, its config's `iou`)."""

    model_config = ConfigDict(extra="forbid")

    merge_iou: float = Field(0.9, ge=0, le=1, description="a prompt's mask merges into an output mask at IoU >= this")
    coverage: float = Field(0.9, ge=0, le=1, description="an everything-mask covered less than this by the outputs seeds a new prompt")


class MaskAtoms:
    """A frame's everything-masks as a partition of its pixels into atoms (pixels in exactly the same masks).

    Attributes:
        labels: (H * W,) int64 atom of every pixel (row-major).
        membership: (atoms, masks) bool: which everything-masks contain each atom.
        counts: (atoms,) pixels per atom; rows, columns: (atoms,) sums of their pixel coordinates.
    """

    def __init__(self, masks: np.ndarray):
        count, self.height, self.width = masks.shape
        pixels = self.height * self.width
        flat = np.ascontiguousarray(masks.reshape(count, pixels))
        words = _pack_words(flat) if count else np.zeros((1, pixels), np.uint64)
        if len(words) == 1:  # up to 64 masks: one compiled pass labels atoms and sums their statistics
            self.labels, distinct, self.counts, self.rows, self.columns = _label_words(words[0], self.width)
            bits = (distinct[:, None] >> np.arange(count, dtype=np.uint64)[None, :]) & np.uint64(1)
            self.membership = bits.astype(bool)
        else:
            self.labels, self.membership = _atoms(words, count)
            atoms = self.membership.shape[0]
            self.counts = np.bincount(self.labels, minlength=atoms).astype(np.int64)
            index = np.arange(pixels)
            self.rows = np.bincount(self.labels, weights=index // self.width, minlength=atoms)
            self.columns = np.bincount(self.labels, weights=index % self.width, minlength=atoms)
        # Empty everything-masks can hold no prompt: they are dropped here.
        self.membership = self.membership[:, self.counts @ self.membership > 0]

    @property
    def masks(self) -> np.ndarray:
        """(masks, atoms) bool: each everything-mask as a set of atoms."""
        return self.membership.T

    def area(self, sets: np.ndarray) -> np.ndarray:
        """Pixel counts of atom sets (..., atoms)."""
        return sets.astype(np.int64) @ self.counts

    def point_prompt(self, row: int, column: int) -> np.ndarray:
        """Atom set of the union of every everything-mask containing pixel (row, column)."""
        containing = self.membership[self.labels[row * self.width + column]]
        return self.membership[:, containing].any(axis=1)

    def prompt_pixel(self, atoms: np.ndarray, rng: np.random.Generator) -> tuple[int, int]:
        """The centroid pixel of a non-empty atom set, or a seeded random pixel of it when the centroid is outside."""
        area = self.area(atoms)
        row, column = int(self.rows[atoms].sum() / area), int(self.columns[atoms].sum() / area)
        if atoms[self.labels[row * self.width + column]]:
            return row, column
        inside = np.flatnonzero(atoms[self.labels])
        pixel = int(inside[rng.integers(inside.size)])
        return pixel // self.width, pixel % self.width

    def dense(self, sets: np.ndarray) -> np.ndarray:
        """(n, atoms) atom sets -> (n, H, W) bool masks."""
        return _dense(np.ascontiguousarray(sets, dtype=np.bool_), self.labels).reshape(len(sets), self.height, self.width)


@numba.njit(cache=True)
def _pack_words(flat: np.ndarray) -> np.ndarray:
    """(masks, pixels) bool -> (ceil(masks / 64), pixels) uint64: bit i % 64 of word i // 64 = in mask i."""
    count, pixels = flat.shape
    words = np.zeros(((count + 63) // 64, pixels), np.uint64)
    for index in range(count):
        word, bit = index // 64, np.uint64(1) << np.uint64(index % 64)
        for pixel in range(pixels):
            if flat[index, pixel]:
                words[word, pixel] |= bit
    return words


@numba.njit(cache=True)
def _label_words(words: np.ndarray, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One word per pixel -> (atom labels in first-seen order, atom words, pixel counts, row sums, column sums)."""
    pixels = words.shape[0]
    table = numba.typed.Dict.empty(key_type=numba.types.uint64, value_type=numba.types.int64)
    labels = np.empty(pixels, np.int64)
    distinct = np.empty(pixels, np.uint64)
    current, previous = -1, np.uint64(0)
    for pixel in range(pixels):
        word = words[pixel]
        if pixel == 0 or word != previous:  # words come in long runs: look up only where they change
            if word in table:
                current = table[word]
            else:
                current = len(table)
                table[word] = current
                distinct[current] = word
            previous = word
        labels[pixel] = current
    atoms = len(table)
    counts = np.zeros(atoms, np.int64)
    rows = np.zeros(atoms, np.float64)
    columns = np.zeros(atoms, np.float64)
    for pixel in range(pixels):
        atom = labels[pixel]
        counts[atom] += 1
        rows[atom] += pixel // width
        columns[atom] += pixel % width
    return labels, distinct[:atoms].copy(), counts, rows, columns


@numba.njit(cache=True)
def _dense(sets: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(n, atoms) atom sets -> (n, pixels) masks, filled run by run of equal labels (10x a per-pixel gather)."""
    count, pixels = sets.shape[0], labels.shape[0]
    out = np.zeros((count, pixels), np.bool_)
    start = 0
    for pixel in range(1, pixels + 1):
        if pixel == pixels or labels[pixel] != labels[start]:
            atom = labels[start]
            for index in range(count):
                if sets[index, atom]:
                    out[index, start:pixel] = True
            start = pixel
    return out


def _atoms(words: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Several words per pixel (more than 64 masks) -> (atom label per pixel, membership (atoms, masks)).

    Labels change rarely along a row, so the distinct words are found among runs of equal words,
    not among all pixels.
    """
    pixels = words.shape[1]
    change = np.zeros(pixels, bool)
    change[0] = True
    change[1:] = (words[:, 1:] != words[:, :-1]).any(axis=0)
    starts = np.flatnonzero(change)
    lengths = np.diff(np.append(starts, pixels))
    distinct, inverse = np.unique(words[:, starts].T, axis=0, return_inverse=True)
    labels = np.repeat(inverse.reshape(-1), lengths).astype(np.int64)
    index = np.arange(count)
    membership = (distinct[:, index // 64] >> (index % 64).astype(np.uint64)) & np.uint64(1)
    return labels, membership.astype(bool)


def _merge(kept: list[np.ndarray], candidate: np.ndarray, counts: np.ndarray, merge_iou: float) -> None:
    """Step 4's rule: OR `candidate` into the kept set of highest IoU if that IoU >= merge_iou, else keep it."""
    if kept:
        stack = np.stack(kept)
        intersection = (stack & candidate).astype(np.int64) @ counts
        union = (stack | candidate).astype(np.int64) @ counts
        iou = np.divide(intersection, union, out=np.zeros(len(kept)), where=union > 0)
        best = int(np.argmax(iou))
        if iou[best] >= merge_iou:
            kept[best] = kept[best] | candidate
            return
    kept.append(candidate)


def _by_area(atoms: MaskAtoms, sets: np.ndarray) -> np.ndarray:
    """Sets sorted by area, largest first; equal areas keep their order."""
    return sets[np.argsort(-atoms.area(sets), kind="stable")]


def self_prompted_masks(atoms: MaskAtoms, prompts: list[tuple[int, int]], options: FastSpamOptions,
                        rng: np.random.Generator) -> np.ndarray:
    """Steps 4-6: the masks of the carried prompts (pixels (row, column), in order), then of the
    everything-masks (largest first) they leave uncovered; empty ones dropped, sorted by area."""
    kept: list[np.ndarray] = []
    for row, column in prompts:
        _merge(kept, atoms.point_prompt(row, column), atoms.counts, options.merge_iou)
    union = np.stack(kept).any(axis=0)
    everything = atoms.masks
    for index in np.argsort(-atoms.area(everything), kind="stable"):
        mask = everything[index]
        if int(atoms.area(mask & union)) / int(atoms.area(mask)) < options.coverage:
            row, column = atoms.prompt_pixel(mask, rng)
            _merge(kept, atoms.point_prompt(row, column), atoms.counts, options.merge_iou)
    sets = np.stack(kept)
    return _by_area(atoms, sets[atoms.area(sets) > 0])


class FastSpam(Segmenter):
    """FastSPAM self-prompting around `segmenter` (see the module doc for the seven steps)."""

    name = "fastspam"

    def __init__(self, segmenter: Segmenter, **options: Any):
        self.segmenter = segmenter
        self.needs_ground_truth = segmenter.needs_ground_truth  # type: ignore[misc]  # the oracle inside still reads it
        self.options = parse_options(FastSpamOptions, "fastspam", options)
        self.memory: np.ndarray = np.zeros((0, 3))
        self._rng = np.random.default_rng(0)

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "segmenter": self.segmenter.describe(), "options": self.options.model_dump()}

    def reset(self, rng: np.random.Generator) -> None:
        """A new video: memory cleared; the wrapped segmenter gets its own generator drawn from `rng`."""
        self.memory = np.zeros((0, 3))
        self._rng = rng
        self.segmenter.reset(np.random.default_rng(int(rng.integers(2**63))))

    def segment(self, frame: FrameInput) -> np.ndarray:
        if frame.depth is None or frame.pose is None or frame.intrinsics is None:
            raise ModelError("self-prompting needs every frame's depth, camera pose and intrinsics; "
                             "predict from a rendered run, or drop --self-prompting")
        atoms = MaskAtoms(self.segmenter.segment(frame))
        prompts = self._reprojected_prompts(frame)
        if not prompts:
            outputs = _by_area(atoms, atoms.masks)
        else:
            outputs = self_prompted_masks(atoms, prompts, self.options, self._rng)
        self.memory = self._remember(atoms, outputs, frame)
        return atoms.dense(outputs)

    def _remember(self, atoms: MaskAtoms, outputs: np.ndarray, frame: FrameInput) -> np.ndarray:
        """World points of the outputs' prompt pixels (in output order); pixels without depth are dropped."""
        assert frame.depth is not None and frame.pose is not None and frame.intrinsics is not None
        pixels = [atoms.prompt_pixel(mask, self._rng) for mask in outputs]
        if not pixels:
            return np.zeros((0, 3))
        rows, columns = (np.array(values, np.int64) for values in zip(*pixels))
        z = frame.depth[rows, columns].astype(np.float64) / 1000.0
        valid = z > 0
        return unproject(columns[valid], rows[valid], z[valid], frame.intrinsics, frame.pose)

    def _reprojected_prompts(self, frame: FrameInput) -> list[tuple[int, int]]:
        """Step 3: the remembered points as pixels (row, column) of this frame, those inside the image."""
        if not len(self.memory):
            return []
        assert frame.intrinsics is not None and frame.pose is not None
        height, width = frame.rgb.shape[:2]
        column, row, z = project(self.memory, frame.intrinsics, frame.pose)
        u, v, inside = pixels_inside(column, row, z, width, height)
        return list(zip(v[inside].tolist(), u[inside].tolist()))
