"""A two-node Ray cluster on this machine, run as its own process by the cluster tests.

Ray's test utility (`ray.cluster_utils.Cluster`) starts real GCS and raylet processes: a head node and
a second node, each with one CPU, on the loopback address and in a temporary folder of their own.
The process prints one JSON line (the address and both node ids), then obeys lines on stdin:
`remove` kills the second node's processes (as if the machine were lost) and answers `removed`;
end of input shuts the cluster down. Ray's reaper processes take the nodes down even if this process
is killed, so a failing test leaves nothing running.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")


def main() -> None:
    """Start the cluster, report it, and follow the commands on stdin."""
    from ray.cluster_utils import Cluster

    temp_dir = tempfile.mkdtemp(prefix="mvpd-ray-")  # short: Ray's socket paths must stay under 108 bytes
    cluster = Cluster(initialize_head=True, head_node_args={
        "num_cpus": 1, "node_ip_address": "127.0.0.1", "temp_dir": temp_dir, "include_dashboard": False,
        "resources": {"head": 1}})
    second = cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1", resources={"second": 1})
    cluster.wait_for_nodes()
    print(json.dumps({"address": cluster.address, "head": cluster.head_node.node_id, "second": second.node_id,
                      "temp_dir": temp_dir}), flush=True)
    try:
        for line in sys.stdin:
            if line.strip() == "remove":
                cluster.remove_node(second, allow_graceful=False)
                print("removed", flush=True)
    finally:
        cluster.shutdown()
        shutil.rmtree(temp_dir, ignore_errors=True)  # the nodes' sessions and logs


if __name__ == "__main__":
    main()
