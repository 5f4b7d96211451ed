"""The marker index on a real S3 API (moto on 127.0.0.1): one LIST gives every marker's ETag, and a marker
rewritten or deleted after the index is seen as such."""

from __future__ import annotations

from pipeline.store.marker_index import INDEX_NAME, FsspecMarkerFolder, load_markers, write_index
from pipeline.store.markers import marker_text
from tests.runtime.test_marker_index import a_marker
from tests.storage.conftest import BUCKET


class CountingS3Folder(FsspecMarkerFolder):
    """The store's folder, counting the markers it fetches one by one."""

    fetched: list[str] = []

    def read_texts(self, names: list[str]) -> dict[str, str]:
        CountingS3Folder.fetched = list(names)
        return super().read_texts(names)


def test_the_index_on_s3_is_trusted_by_etag(s3):
    base = f"{BUCKET}/marker-index/_state/render"
    markers = {f"u{index}": a_marker(f"u{index}", files=index + 1) for index in range(5)}
    for unit, marker in markers.items():
        s3.fs.pipe_file(f"{base}/{unit}.json", marker_text(marker).encode())
    folder = CountingS3Folder(s3.fs, base)
    assert write_index(folder) == 5 and s3.fs.exists(f"{base}/{INDEX_NAME}")
    assert load_markers(folder) == markers and CountingS3Folder.fetched == []
    markers["u1"] = a_marker("u1", files=7, seconds=9.0)
    s3.fs.pipe_file(f"{base}/u1.json", marker_text(markers["u1"]).encode())
    s3.fs.rm(f"{base}/u3.json")
    del markers["u3"]
    assert load_markers(folder) == markers and CountingS3Folder.fetched == ["u1.json"]
    s3.fs.pipe_file(f"{base}/{INDEX_NAME}", b"not parquet")
    assert load_markers(folder) == markers
