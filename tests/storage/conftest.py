"""An S3 API on 127.0.0.1 (moto's threaded server, started here) and the environment that points s3fs at it.

The endpoint and test credentials go into environment variables only (set here, restored afterwards), the
way a user's real ones would; the real AWS is never contacted.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterator

import pytest

TEST_SECRET = "mvpd-test-secret-never-written"
TEST_KEY_ID = "MVPDTESTKEYID0000000"
BUCKET = "mvpd-test"


class S3Server:
    """The running server: its endpoint and a client on it."""

    def __init__(self, endpoint: str, cache: Path):
        import s3fs

        self.endpoint = endpoint
        self.cache = cache
        self.fs = s3fs.S3FileSystem()

    def url(self, prefix: str) -> str:
        return f"s3://{BUCKET}/{prefix}"


def storage_environment(endpoint: str, cache: Path) -> dict[str, str]:
    return {"AWS_ACCESS_KEY_ID": TEST_KEY_ID, "AWS_SECRET_ACCESS_KEY": TEST_SECRET, "AWS_ENDPOINT_URL": endpoint,
            "AWS_DEFAULT_REGION": "us-east-1", "MVPD_CACHE_DIR": str(cache)}


def forget_clients() -> None:
    """s3fs caches clients by their options, not by the environment: drop them after changing it."""
    import s3fs

    s3fs.S3FileSystem.clear_instance_cache()


@pytest.fixture(scope="session")
def s3(tmp_path_factory: pytest.TempPathFactory) -> Iterator[S3Server]:
    from moto.server import ThreadedMotoServer

    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    environment = storage_environment(f"http://{host}:{port}", tmp_path_factory.mktemp("s3-cache"))
    saved = {name: os.environ.get(name) for name in [*environment, "AWS_PROFILE", "AWS_SESSION_TOKEN"]}
    os.environ.pop("AWS_PROFILE", None)
    os.environ.pop("AWS_SESSION_TOKEN", None)
    os.environ.update(environment)
    forget_clients()
    try:
        running = S3Server(environment["AWS_ENDPOINT_URL"], Path(environment["MVPD_CACHE_DIR"]))
        running.fs.mkdir(BUCKET)
        yield running
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        forget_clients()
        server.stop()
