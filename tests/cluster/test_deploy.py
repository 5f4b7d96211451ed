"""deploy/: the cluster files parse and say what matters: the image, an entrypoint joining the cluster with
the run folder on object storage, credentials from a Secret or env file, and no shared volume.
(Docker is not available here; the Dockerfile's install step was run in a clean venv, see the README.)"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Iterator

import yaml

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
IMAGE = "mvpd-pipeline:0.1.0"
CREDENTIALS = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_ENDPOINT_URL")


def walk(node: Any) -> Iterator[tuple[str, Any]]:
    """Every (key, value) pair of a parsed YAML document, at any depth."""
    if isinstance(node, dict):
        for key, value in node.items():
            yield key, value
            yield from walk(value)
    elif isinstance(node, list):
        for item in node:
            yield from walk(item)


def test_the_rayjob_runs_the_job_on_object_storage_with_credentials_from_a_secret() -> None:
    job = yaml.safe_load((DEPLOY / "kuberay-rayjob.yaml").read_text())
    assert job["kind"] == "RayJob" and job["apiVersion"] == "ray.io/v1"
    entrypoint = job["spec"]["entrypoint"].split()
    assert entrypoint[:2] == ["mvpd", "submit"] and "--address" in entrypoint
    assert entrypoint[entrypoint.index("--run-dir") + 1].startswith("s3://")
    cluster = job["spec"]["rayClusterSpec"]
    pods = [cluster["headGroupSpec"]["template"]["spec"]] + [g["template"]["spec"] for g in cluster["workerGroupSpecs"]]
    for pod in pods:
        for container in pod["containers"] + pod.get("initContainers", []):
            assert container["image"] == IMAGE
            assert {"secretRef": {"name": "mvpd-s3"}} in container["envFrom"], container["name"]
        assert all("emptyDir" in volume for volume in pod.get("volumes", []))  # each pod's own disk
    keys = {key for key, _ in walk(job)}
    assert "persistentVolumeClaim" not in keys and "nfs" not in keys and "hostPath" not in keys
    text = (DEPLOY / "kuberay-rayjob.yaml").read_text()
    assert all(name in text for name in CREDENTIALS)  # the comment says how to make the Secret


def test_the_cluster_launcher_reads_credentials_from_an_env_file_and_mounts_no_shared_volume() -> None:
    text = (DEPLOY / "ray-cluster.yaml").read_text()
    launcher = yaml.safe_load(text)
    assert launcher["docker"]["image"] == IMAGE
    options = " ".join(launcher["docker"]["run_options"])
    assert "--env-file /etc/mvpd/s3.env" in options and "-v " not in options and "--volume" not in options
    assert "/etc/mvpd/s3.env" in launcher["file_mounts"]
    assert any(c.startswith("ray start --head") for c in launcher["head_start_ray_commands"])
    assert any("--address=" in c for c in launcher["worker_start_ray_commands"])
    submit = re.search(r"'(mvpd submit [^']+)'", text)
    assert submit and "--address" in submit.group(1) and "--run-dir s3://" in submit.group(1)
    assert all(name in text for name in CREDENTIALS)


def test_the_dockerfile_installs_the_package_with_s3_support_and_no_credentials() -> None:
    text = (DEPLOY / "Dockerfile").read_text()
    runs = [line for line in text.splitlines() if line.startswith("RUN ")]
    assert any(re.search(r"pip install .*\.$", line) for line in runs)
    import tomllib

    dependencies = tomllib.loads((DEPLOY.parent / "pyproject.toml").read_text())["project"]["dependencies"]
    assert any(d.startswith("s3fs") for d in dependencies)  # the package itself reads s3:// run folders
    assert not re.search(r"^ENV AWS_", text, flags=re.MULTILINE)  # credentials come from the environment
