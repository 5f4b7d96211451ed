"""MVPd release export and import: our run layout <-> MVPd's (schemas/mvpd.md)."""

from pipeline.io.mvpd.export import ExportSummary, MvpdExportError, export_release, export_release_splits
from pipeline.io.mvpd.importer import ImportSummary, MvpdImportError, import_release
from pipeline.io.mvpd.layout import MvpdFormatError, pose_from_mvpd, pose_to_mvpd

__all__ = [
    "ExportSummary", "ImportSummary", "MvpdExportError", "MvpdFormatError", "MvpdImportError",
    "export_release", "export_release_splits", "import_release", "pose_from_mvpd", "pose_to_mvpd",
]
