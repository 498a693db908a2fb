"""A local S3 server that counts the requests it answers, by HTTP method.

The control plane's cost on S3 is its request count (each LIST page, HEAD,
GET and PUT is billed and takes a round trip), so tests and the control-root
benchmark measure it at the server::

    with counting_s3_server() as (server, counter):
        counter.reset()
        ...  # the code under test
        assert counter.total() <= bound
"""

from __future__ import annotations

import contextlib
import threading
from collections import Counter
from typing import Iterator

from tests.s3_server import S3Server, local_s3_server


class RequestCounter:
    """Requests per HTTP method (thread-safe: the server answers from many threads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: Counter[str] = Counter()

    def add(self, method: str) -> None:
        with self._lock:
            self._counts[method] += 1

    def reset(self) -> None:
        with self._lock:
            self._counts.clear()

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def total(self) -> int:
        return sum(self.counts().values())


def _counting_server_class(counter: RequestCounter):
    from moto.server import DomainDispatcherApplication, MotoRequestHandler, ThreadedMotoServer, create_backend_app
    from werkzeug.serving import make_server

    class CountingMotoServer(ThreadedMotoServer):
        def _server_entry(self) -> None:
            app = DomainDispatcherApplication(create_backend_app)

            def counting_app(environ, start_response):
                if not environ.get("PATH_INFO", "").startswith("/moto-api"):
                    counter.add(environ.get("REQUEST_METHOD", "?"))
                return app(environ, start_response)

            self._server = make_server(self._ip_address, self._port, counting_app, True, request_handler=MotoRequestHandler)
            self._server_ready_event.set()
            self._server.serve_forever()

    return CountingMotoServer


@contextlib.contextmanager
def counting_s3_server(bucket: str = "idda-test") -> Iterator[tuple[S3Server, RequestCounter]]:
    """A local S3 server (see tests.s3_server.local_s3_server) and its request counter."""
    counter = RequestCounter()
    with local_s3_server(bucket, server_class=_counting_server_class(counter)) as server:
        yield server, counter
