"""Parquet shards of one split, written row group by row group as frames arrive (memory flat in the videos).

Rows are buffered until a row group is full (`rows_per_group`, fixed, so the same run gives the same
bytes), written, and the shard is closed once its file passes `shard_bytes`; the next row starts a new
shard. Shards are named `<split>-<index:05d>-of-<count:05d>.parquet` once the split is complete (the
Hub's convention), so only `finish` knows the count and renames them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

# Frames per row group: `datasets` reads (and streams) one row group per batch; ~64 x 0.4-1 MB per frame at
# 640x480 keeps a batch well under the Hub viewer's limits and the writer's buffer small.
ROWS_PER_GROUP = 64
# A shard closes once its file passes this size: "a few hundred MB", as the Hub's own uploads shard.
SHARD_BYTES = 256 * 2**20
# Compressing PNG bytes again gains nothing: only the arrays, lists and strings are zstd-compressed.
IMAGE_COLUMNS = ("rgb", "depth")


@dataclass
class SplitShards:
    """What a split's shards hold, for the dataset card."""

    files: list[Path] = field(default_factory=list)
    rows: int = 0
    arrow_bytes: int = 0  # in-memory Arrow size of the rows (`datasets`' num_bytes)

    @property
    def file_bytes(self) -> int:
        return sum(path.stat().st_size for path in self.files)


class ShardWriter:
    """Writes one split's rows into `folder` as size-bounded Parquet shards.

    Args:
        folder: where the shards go (the staging copy of `data/`).
        split: split name (the shard files' prefix).
        schema: the Parquet schema (features.parquet_schema).
        rows_per_group, shard_bytes: the fixed row group size and the shard size bound.
    """

    def __init__(self, folder: Path, split: str, schema: pa.Schema, rows_per_group: int = ROWS_PER_GROUP,
                 shard_bytes: int = SHARD_BYTES):
        self.folder, self.split, self.schema = folder, split, schema
        self.rows_per_group, self.shard_bytes = rows_per_group, shard_bytes
        self.pending: list[pa.RecordBatch] = []
        self.writer: pq.ParquetWriter | None = None
        self.sink: pa.NativeFile | None = None
        self.shards = SplitShards()

    def add(self, batch: pa.RecordBatch) -> None:
        """Queue rows; full row groups are written at once."""
        self.pending.append(batch)
        self.shards.rows += batch.num_rows
        self.shards.arrow_bytes += batch.nbytes
        while sum(b.num_rows for b in self.pending) >= self.rows_per_group:
            table = pa.Table.from_batches(self.pending, self.schema)
            self._write_group(table.slice(0, self.rows_per_group))
            self.pending = table.slice(self.rows_per_group).to_batches()

    def finish(self) -> SplitShards:
        """Write the last (shorter) row group, close the shard and give every shard its final name."""
        if self.pending:
            self._write_group(pa.Table.from_batches(self.pending, self.schema))
            self.pending = []
        self._close_shard()
        count = len(self.shards.files)
        named = []
        for index, path in enumerate(self.shards.files):
            final = path.with_name(f"{self.split}-{index:05d}-of-{count:05d}.parquet")
            path.rename(final)
            named.append(final)
        self.shards.files = named
        return self.shards

    def close(self) -> None:
        """Release an open shard after a failure (the staging folder is removed by the caller)."""
        self._close_shard()

    def _write_group(self, table: pa.Table) -> None:
        if self.writer is None:
            path = self.folder / f"{self.split}-{len(self.shards.files):05d}.parquet"
            self.shards.files.append(path)
            self.sink = pa.OSFile(str(path), "wb")
            self.writer = pq.ParquetWriter(
                self.sink, self.schema,
                compression={name: "none" if name in IMAGE_COLUMNS else "zstd" for name in self.schema.names},
                # Min/max statistics of image bytes would copy whole PNGs into the footer: none for them.
                write_statistics=[name for name in self.schema.names if name not in IMAGE_COLUMNS])
        self.writer.write_table(table, row_group_size=self.rows_per_group)
        if self.sink is not None and self.sink.tell() >= self.shard_bytes:
            self._close_shard()

    def _close_shard(self) -> None:
        if self.writer is not None:
            self.writer.close()  # writes the footer
            self.writer = None
        if self.sink is not None:
            self.sink.close()
            self.sink = None
