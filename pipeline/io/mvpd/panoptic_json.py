"""`panoptic_<split>.json` written one video at a time, so an export's memory does not grow with the split.

The file is one JSON object whose three long lists (`videos`, `annotations`, `instances`) each take one
entry per video. Holding them all until the end cost 0.87 GiB at 1 % of MVPd (so ~90 GiB for the release).
Instead each finished video's entries are appended as JSON text to three spool files beside the output,
and `finish` joins them into the file: the same bytes as `write_json` of the whole object, since
`json.dumps` writes a list as "[" + ", ".join(items) + "]" with the separators used here.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import IO, Any

from pipeline.io.mvpd.layout import mvpd_categories
from pipeline.store.names import replaced

SEPARATORS = (", ", ": ")  # write_json's
LISTS = ("videos", "annotations")  # then "categories" (fixed), then "instances"


class PanopticJsonSpool:
    """Appends videos' entries to spool files in `folder`; `finish` writes `folder/<name>` from them."""

    def __init__(self, folder: Path, name: str):
        self.path = folder / name
        # Anonymous files in the output folder (no name a link could sit at), gone when closed.
        self._spools = {key: tempfile.TemporaryFile("w+", encoding="utf-8", dir=folder)
                        for key in (*LISTS, "instances")}
        self._count = dict.fromkeys(self._spools, 0)

    def add(self, name: str, images: list[dict[str, Any]], annotations: list[dict[str, Any]],
            instance_id_map: dict[str, Any], instances: list[dict[str, Any]]) -> None:
        """One video's entries, in the order the videos are to appear."""
        self._append("videos", [{"video_id": name, "video_name": name, "images": images}])
        self._append("annotations", [{"video_id": name, "video_name": name, "annotations": annotations,
                                      "instance_id_map": instance_id_map}])
        self._append("instances", instances)

    def finish(self) -> None:
        """Write the JSON file and remove the spools."""
        with replaced(self.path) as temporary, open(temporary, "w", encoding="utf-8") as out:
            for key in LISTS:
                out.write(("{" if key == LISTS[0] else ", ") + json.dumps(key) + ": [")
                self._copy(key, out)
                out.write("]")
            out.write(', "categories": ' + json.dumps(mvpd_categories(), separators=SEPARATORS))
            out.write(', "instances": [')
            self._copy("instances", out)
            out.write("]}")
        self.close()

    def close(self) -> None:
        """Close (and so remove) the spools (idempotent)."""
        for spool in self._spools.values():
            spool.close()

    def _append(self, key: str, entries: list[dict[str, Any]]) -> None:
        spool = self._spools[key]
        for entry in entries:
            spool.write((", " if self._count[key] else "") + json.dumps(entry, separators=SEPARATORS))
            self._count[key] += 1

    def _copy(self, key: str, out: IO[str]) -> None:
        spool = self._spools[key]
        spool.seek(0)
        shutil.copyfileobj(spool, out)
