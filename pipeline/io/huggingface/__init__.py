"""A run as a Hugging Face dataset folder that `datasets.load_dataset` loads and streams (`mvpd export --hf`)."""

from pipeline.io.huggingface.export import HfExportError, HfExportSummary, export_hf_dataset

__all__ = ["HfExportError", "HfExportSummary", "export_hf_dataset"]
