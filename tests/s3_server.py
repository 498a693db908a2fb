"""A local S3-compatible server (moto) on 127.0.0.1 for tests.

Use the context manager directly, or the module-scoped ``s3_server`` fixture::

    from tests.s3_server import s3_server  # noqa: F401  (registers the fixture)

    def test_round_trip(s3_server):
        storage = Storage.from_uri(s3_server.uri("run1"))

While it runs, the environment points the code under test at the server
(AWS_ENDPOINT_URL_S3, dummy credentials, region); everything is restored, and
the server's state reset, on exit.
"""

from __future__ import annotations

import contextlib
import logging
import os
import urllib.request
from dataclasses import dataclass, field
from typing import Callable, Iterator

import pytest

ACCESS_KEY = "idda-test-access-key"
SECRET_KEY = "idda-test-secret-key-never-print-me"
REGION = "us-east-1"
# Variables that could point the code elsewhere; cleared while the server runs.
_CLEARED = (
    "IDDA_S3_ENDPOINT",
    "AWS_ENDPOINT_URL",
    "AWS_SESSION_TOKEN",
    "AWS_PROFILE",
    "AWS_ROLE_ARN",
    "AWS_WEB_IDENTITY_TOKEN_FILE",
)


@dataclass(frozen=True)
class S3Server:
    """A running local server: its endpoint URL and the bucket created on it."""

    endpoint: str  # "http://127.0.0.1:<port>"
    bucket: str
    moto: object = field(default=None, compare=False, repr=False)  # the server itself (tests/faultkit.s3_outage stops it)
    stop: Callable[[], None] = field(default=lambda: None, compare=False, repr=False)  # the endpoint goes away now (an outage)

    def uri(self, prefix: str = "") -> str:
        """``s3://<bucket>/<prefix>`` on this server."""
        return f"s3://{self.bucket}/{prefix}".rstrip("/")


@contextlib.contextmanager
def local_s3_server(bucket: str = "idda-test", server_class=None) -> Iterator[S3Server]:
    """Start moto on a free port, set the S3 environment, create ``bucket``; undo it all on exit.

    ``server_class``: a ThreadedMotoServer subclass to run instead (tests.s3_counter counts requests)."""
    try:
        import boto3
        from moto.server import ThreadedMotoServer
    except ImportError as exc:
        raise ImportError(
            "the local S3 server needs moto[server] and boto3: pip install -e '.[test]'"
        ) from exc

    werkzeug_log = logging.getLogger("werkzeug")
    old_level = werkzeug_log.level
    werkzeug_log.setLevel(logging.WARNING)  # no line per request
    server = (server_class or ThreadedMotoServer)(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    stopped: list[bool] = []

    def stop() -> None:
        if not stopped:
            stopped.append(True)
            server.stop()

    host, port = server.get_host_and_port()
    endpoint = f"http://{host}:{port}"
    env = {
        "AWS_ENDPOINT_URL_S3": endpoint,
        "AWS_ACCESS_KEY_ID": ACCESS_KEY,
        "AWS_SECRET_ACCESS_KEY": SECRET_KEY,
        "AWS_REGION": REGION,
        "AWS_DEFAULT_REGION": REGION,
        "AWS_EC2_METADATA_DISABLED": "true",
    }
    saved = {name: os.environ.get(name) for name in (*env, *_CLEARED)}
    try:
        for name in _CLEARED:
            os.environ.pop(name, None)
        os.environ.update(env)
        client = boto3.client(
            "s3",
            endpoint_url=endpoint,
            region_name=REGION,
            aws_access_key_id=ACCESS_KEY,
            aws_secret_access_key=SECRET_KEY,
        )
        client.create_bucket(Bucket=bucket)
        yield S3Server(endpoint=endpoint, bucket=bucket, moto=server, stop=stop)
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
        if not stopped:
            with contextlib.suppress(OSError):  # moto keeps state per process; drop it (fails fast if stopped)
                urllib.request.urlopen(
                    urllib.request.Request(f"{endpoint}/moto-api/reset", method="POST"), timeout=10
                ).close()
        stop()
        werkzeug_log.setLevel(old_level)


@pytest.fixture(scope="module")
def s3_server() -> Iterator[S3Server]:
    """A local S3 server for the whole test module (see :func:`local_s3_server`)."""
    with local_s3_server() as server:
        yield server
