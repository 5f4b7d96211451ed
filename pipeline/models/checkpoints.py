"""Local weights and optional extras for the segmenters that need them (`ultralytics`, `sam`).

Both adapters take their weights from a file the user names and never download anything; a missing
package or file is one `ModelError` line saying what to install or pass.
"""

from __future__ import annotations

import importlib
import pickle
from pathlib import Path
from types import ModuleType

from pipeline.models.segmenter import ModelError

# What torch.load and load_state_dict raise for a file that is not the expected checkpoint (truncated,
# another network's weights, not a pickle at all).
CHECKPOINT_LOAD_ERRORS = (RuntimeError, KeyError, IndexError, AttributeError, ValueError, TypeError, EOFError,
                          pickle.UnpicklingError)


def one_line(error: BaseException, limit: int = 200) -> str:
    """A library's (often multi-line) error message as one line of at most `limit` characters."""
    text = " ".join(str(error).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def require_checkpoint(checkpoint: str | Path | None, model: str, example: str) -> Path:
    """The checkpoint as an existing local file; ModelError naming the option and an example otherwise."""
    if checkpoint is None or str(checkpoint) == "":
        raise ModelError(f"model {model!r} needs a local checkpoint file: pass checkpoint=PATH (e.g. {example}); "
                         "it never downloads weights")
    path = Path(checkpoint).expanduser()
    if not path.is_file():
        raise ModelError(f"{path}: no such checkpoint file for model {model!r}; download {example} yourself "
                         "and pass its path (weights are never downloaded)")
    return path.resolve()


def import_extra(module: str, extra: str, model: str) -> ModuleType:
    """Import an optional extra's package; ModelError with the pip command when it (or torch) is missing."""
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise ModelError(f"model {model!r} needs the optional extra {extra!r} ({one_line(error)}); install it with "
                         f"pip install 'mvpd-pipeline[{extra}]'") from None
