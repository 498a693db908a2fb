"""Output-root URIs, S3 settings from the environment, and relative-path checks."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from urllib.parse import unquote, urlsplit

from storage.errors import StorageError, redact

SUPPORTED = "a local path, file:///abs/path, s3://bucket/prefix"
_BUCKET_RE = re.compile(r"^[a-z0-9][a-z0-9.\-]{1,61}[a-z0-9]$")
# Checked in this order; the first one set wins.
ENDPOINT_ENV = ("IDDA_S3_ENDPOINT", "AWS_ENDPOINT_URL_S3", "AWS_ENDPOINT_URL")
REGION_ENV = ("AWS_REGION", "AWS_DEFAULT_REGION")


@dataclass(frozen=True)
class Location:
    """Where an output root lives: ``kind`` names the backend, ``base`` is its filesystem path."""

    kind: str  # "local" or "s3"
    base: str  # "/abs/dir" for local, "bucket/prefix" (no slashes at the ends) for s3

    @property
    def uri(self) -> str:
        return self.base if self.kind == "local" else f"s3://{self.base}"

    def fs_path(self, rel: str) -> str:
        """The pyarrow filesystem path of ``rel`` (already cleaned)."""
        if not rel:
            return self.base
        return f"{self.base.rstrip('/')}/{rel}"

    def join(self, rel: str) -> str:
        path = self.fs_path(rel)
        return path if self.kind == "local" else f"s3://{path}"


@dataclass(frozen=True)
class S3Config:
    """S3 connection settings (never credentials) read from the environment."""

    endpoint: str | None = None  # "host[:port]" for endpoint_override
    scheme: str = "https"
    region: str | None = None

    @classmethod
    def from_env(cls) -> S3Config:
        raw = next((os.environ[k] for k in ENDPOINT_ENV if os.environ.get(k)), None)
        region = next((os.environ[k] for k in REGION_ENV if os.environ.get(k)), None)
        if raw is None:
            return cls(region=region)
        parts = urlsplit(raw if "://" in raw else f"https://{raw}")
        if parts.username or parts.password:
            raise StorageError(
                f"S3 endpoint {redact(raw)} embeds credentials; set AWS_ACCESS_KEY_ID and "
                "AWS_SECRET_ACCESS_KEY instead"
            )
        if parts.scheme not in ("http", "https") or not parts.netloc or parts.path not in ("", "/"):
            raise StorageError(f"S3 endpoint {redact(raw)} is not of the form http(s)://host[:port]")
        return cls(endpoint=parts.netloc, scheme=parts.scheme, region=region)


def parse_root(uri: str) -> Location:
    """Parse an output-root URI; raises StorageError for anything unsupported."""
    if not isinstance(uri, str) or not uri.strip():
        raise StorageError(f"empty output root; expected {SUPPORTED}")
    if "://" not in uri:
        return _local(uri)
    scheme = uri.split("://", 1)[0].lower()
    parser = _PARSERS.get(scheme)
    if parser is None:
        shown = redact(uri)
        raise StorageError(f"unsupported output root {shown} (scheme {scheme!r}); expected {SUPPORTED}")
    return parser(uri)


def _local(path: str) -> Location:
    if "\x00" in path:
        raise StorageError("local output root contains a NUL character")
    return Location("local", os.path.abspath(os.path.expanduser(path)))


def _parse_file(uri: str) -> Location:
    parts = urlsplit(uri)
    if parts.username or parts.password or parts.netloc not in ("", "localhost"):
        raise StorageError(f"file URI {redact(uri)} must have no host: use file:///abs/path")
    if parts.query or parts.fragment or not parts.path.startswith("/"):
        raise StorageError(f"file URI {redact(uri)} must be file:///abs/path with no query")
    return _local(unquote(parts.path))


def _parse_s3(uri: str) -> Location:
    rest = uri.split("://", 1)[1]
    netloc = rest.split("/", 1)[0]
    if "@" in netloc:
        raise StorageError(
            f"S3 URI {redact(uri)} embeds credentials; remove them and set AWS_ACCESS_KEY_ID "
            "and AWS_SECRET_ACCESS_KEY in the environment"
        )
    if "?" in rest or "#" in rest:
        # Query strings can carry secrets (access_key=...); never echo them.
        raise StorageError(
            f"S3 URI s3://{netloc}/... has a query or fragment; configure S3 through the "
            "environment (AWS_ENDPOINT_URL_S3, AWS_REGION, AWS_ACCESS_KEY_ID, ...)"
        )
    bucket, _, prefix = rest.partition("/")
    if not _BUCKET_RE.match(bucket):
        raise StorageError(f"S3 URI {uri} has no valid bucket name (got {bucket!r})")
    parts = [p for p in prefix.split("/") if p not in ("", ".")]
    if ".." in parts:
        raise StorageError(f"S3 URI {uri} must not contain '..'")
    return Location("s3", "/".join([bucket, *parts]))


_PARSERS = {"file": _parse_file, "s3": _parse_s3}


def clean_rel(rel: str, *, allow_empty: bool = False) -> str:
    """Normalise a '/'-separated path relative to the root; ValueError if it escapes it."""
    if not isinstance(rel, str):
        raise ValueError(f"relative path must be a str, got {type(rel).__name__}")
    if rel.startswith("/") or "\x00" in rel:
        raise ValueError(f"path {rel!r} must be relative to the output root")
    parts = [p for p in rel.split("/") if p not in ("", ".")]
    if ".." in parts:
        raise ValueError(f"path {rel!r} must not contain '..'")
    if not parts and not allow_empty:
        raise ValueError("empty relative path")
    return "/".join(parts)
