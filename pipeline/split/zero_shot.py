"""The zero-shot subset (MVPd's): cluster object names, hold out the clusters training sees least.

The sorted set of unique raw names of the instances of the clustered categories (39 objects, 40 misc)
in the training scenes and the held-out pool is embedded (`encoders.py`) and clustered by k-means
(k-means++, `n_init` restarts, `random_state` seed: the call the authors made with an older
scikit-learn whose default was 10 restarts). Clusters are ranked by the number of training videos
that show an instance of any of their names (ties: lower cluster index first); the
`round(clusters * unseen_fraction)` least-seen clusters are unseen. Pure functions of tables: the
stage (`stage.py`) reads the Parquet and writes the results.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from pipeline.config import ConfigError, ZeroShotConfig
from pipeline.split.encoders import TextEncoder, make_encoder

Video = tuple[str, str]  # (embodiment, video_name)
InstanceKey = tuple[str, int]  # (scene_id, object_id)
EXAMPLE_NAMES = 5


class ZeroShotError(ConfigError):
    """The names cannot be clustered as configured; the message names the field and the fix."""


@dataclass(frozen=True)
class Instance:
    """One object instance of a clustered category."""

    scene_id: str
    object_id: int
    raw_name: str


@dataclass
class ZeroShotOutcome:
    """Clusters (ranked), the cluster of every name, and the unseen instances."""

    encoder: str
    cluster_of_name: dict[str, int]
    clusters: list[dict] = field(default_factory=list)  # rows of `zero_shot_clusters`
    unseen_clusters: set[int] = field(default_factory=set)

    def is_unseen(self, name: str) -> bool:
        return self.cluster_of_name[name] in self.unseen_clusters


class ZeroShotSplitter:
    """Clusters names with the configured encoder and k-means and picks the unseen clusters."""

    def __init__(self, config: ZeroShotConfig, encoder: TextEncoder | None = None):
        self.config = config
        self.encoder = encoder or make_encoder(config)

    def split(self, instances: list[Instance], videos_of: dict[InstanceKey, set[Video]],
              train_scenes: set[str]) -> ZeroShotOutcome:
        """Cluster the names of `instances` and rank clusters by the training videos (`videos_of`) they appear in."""
        names = sorted({instance.raw_name for instance in instances})
        labels = self.cluster(names)
        cluster_of_name = dict(zip(names, (int(label) for label in labels)))
        training_videos: dict[int, set[Video]] = defaultdict(set)
        videos_of_name: dict[str, set[Video]] = defaultdict(set)
        for instance in instances:
            if instance.scene_id in train_scenes:
                seen_in = videos_of.get((instance.scene_id, instance.object_id), set())
                training_videos[cluster_of_name[instance.raw_name]] |= seen_in
                videos_of_name[instance.raw_name] |= seen_in
        return self._rank(cluster_of_name, training_videos, videos_of_name)

    def cluster(self, names: list[str]) -> np.ndarray:
        """k-means cluster index of each name (sorted unique names in, one label per name out)."""
        from sklearn.cluster import KMeans

        if len(names) < self.config.clusters:
            raise ZeroShotError(f"split.zero_shot.clusters: {self.config.clusters} clusters but only {len(names)} unique "
                                f"names in categories {self.config.categories}; lower clusters to at most {len(names)}")
        embeddings = self.encoder.encode(names)
        kmeans = KMeans(n_clusters=self.config.clusters, init="k-means++", n_init=self.config.n_init,
                        random_state=self.config.seed)
        return kmeans.fit_predict(embeddings)

    def _rank(self, cluster_of_name: dict[str, int], training_videos: dict[int, set[Video]],
              videos_of_name: dict[str, set[Video]]) -> ZeroShotOutcome:
        counts = {c: len(training_videos.get(c, ())) for c in range(self.config.clusters)}
        order = sorted(counts, key=lambda c: (counts[c], c))
        unseen_count = max(1, int(round(self.config.clusters * self.config.unseen_fraction)))
        unseen = set(order[:unseen_count])
        names_of: dict[int, list[str]] = defaultdict(list)
        for name, cluster in cluster_of_name.items():
            names_of[cluster].append(name)
        rows = []
        for rank, cluster in enumerate(order):
            examples = sorted(names_of[cluster], key=lambda n: (-len(videos_of_name.get(n, ())), n))[:EXAMPLE_NAMES]
            rows.append({"cluster": cluster, "size": len(names_of[cluster]), "training_videos": counts[cluster],
                         "rank": rank, "unseen": cluster in unseen, "example_names": examples,
                         "encoder": self.encoder.description})
        return ZeroShotOutcome(self.encoder.description, cluster_of_name, sorted(rows, key=lambda r: r["cluster"]), unseen)
