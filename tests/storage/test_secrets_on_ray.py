"""Credentials reach Ray workers without passing through Ray's runtime_env or any log (issue 20, point 3).

Ray writes a task's runtime_env into its session logs (mode 0644, in a world-readable folder): after an S3
run on Ray, no file of Ray's session, of the run's local folder or of the bucket may hold the secret.
"""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from pipeline.cli.main import app
from tests.storage.conftest import TEST_KEY_ID, TEST_SECRET
from tests.storage.test_lock_gc import TINY_JOB

SECRETS = (TEST_SECRET.encode(), TEST_KEY_ID.encode())


def files_holding_a_secret(folder: Path) -> list[str]:
    found = []
    for path in folder.rglob("*"):
        try:
            if path.is_file() and path.stat().st_size < 64 * 2**20:
                data = path.read_bytes()
                found.extend(f"{path}: {secret.decode()}" for secret in SECRETS if secret in data)
        except OSError:  # a socket, or a file Ray removed meanwhile
            continue
    return found


def test_an_s3_run_on_ray_writes_no_credential_into_rays_logs_or_the_run(s3, ray_session, tmp_path):
    import ray

    (tmp_path / "tiny.yaml").write_text(TINY_JOB, encoding="utf-8")
    url = s3.url("runs/secrets-on-ray")
    result = CliRunner().invoke(app, ["submit", str(tmp_path / "tiny.yaml"), "--run-dir", url, "--stages", "shard",
                                      "--executor", "ray"])
    assert result.exit_code == 0 and "shard: 2 done, 0 failed" in result.output, result.output
    session = Path(ray._private.worker._global_node.get_session_dir_path())
    assert list(session.glob("logs/*.log")), session  # Ray's logs are where we look
    assert files_holding_a_secret(session) == []
    assert files_holding_a_secret(s3.cache) == []
    objects = s3.fs.find(url.removeprefix("s3://"))
    assert objects and not [key for key in objects if any(secret in s3.fs.cat_file(key) for secret in SECRETS)]
