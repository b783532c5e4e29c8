"""Inputs and outputs in an object store: a URL with a scheme other than ``file://``
(``s3://bucket/prefix/…``, or any other filesystem fsspec knows) is opened with fsspec; a plain
path or a ``file://`` URL stays a local path, handled as before.

mireg reads and writes local files, so a task downloads a remote input into a local temporary
directory, runs mireg there and uploads the output with :func:`upload`, which never lets a reader
see a partial object under the final key (see :func:`_publish`).

Errors from the store (a missing bucket, an unreachable endpoint, no permission) become
:class:`StoreError`, one line that names the URL.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import posixpath
import re
import uuid
from pathlib import Path

# A temporary key beside the final one: ``.<name>.tmp-<32 hex digits>``.
TEMP_NAME = re.compile(r"^\.(?P<name>.+)\.tmp-[0-9a-f]{32}$")


class StoreError(RuntimeError):
    """A store operation failed; the message is one line and names the URL."""


def is_remote(url: str) -> bool:
    return "://" in url and not url.startswith("file://")


def local_path(url: str) -> str:
    """A plain path for a plain path or a ``file://`` URL."""
    return url[len("file://"):] if url.startswith("file://") else url


def parse_options(pairs: list[str] | None) -> dict:
    """``KEY=VALUE`` pairs as fsspec storage options; a VALUE that parses as JSON (``true``,
    ``5``, ``{"region_name": "eu-west-1"}``) is taken as such, any other as a string."""
    options = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise StoreError(f"--storage-option {pair!r}: expected KEY=VALUE")
        try:
            options[key] = json.loads(value)
        except json.JSONDecodeError:
            options[key] = value
    return options


def join(base: str, *parts: str) -> str:
    """``base/part/…`` for a local directory or a URL."""
    if is_remote(base):
        return posixpath.join(base.rstrip("/"), *parts)
    return str(Path(base, *parts))


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[0]}" if text else type(e).__name__


@contextlib.contextmanager
def _naming(url: str):
    """Turns any error of the store into a StoreError naming ``url``."""
    try:
        yield
    except StoreError:
        raise
    except Exception as e:  # noqa: BLE001 -- whatever the backend raises, one line naming the URL
        raise StoreError(f"{url}: {_one_line(e)}") from e


def _filesystem(url: str, options: dict):
    import fsspec

    # No listing cache: whether an output exists, what the glob matches and which temporary
    # objects are left must be read from the store as it is now, not as it was listed earlier.
    with _naming(url):
        fs, path = fsspec.core.url_to_fs(url, **{"use_listings_cache": False, **options})
    return fs, path.rstrip("/")


def _url(fs, path: str) -> str:
    return fs.unstrip_protocol(path)


def require(url: str, options: dict) -> None:
    """Fails early, with a clear message, when the endpoint cannot be reached or the bucket does
    not exist (a glob in a missing bucket would otherwise just match nothing). On stores whose
    paths start at a root (``memory://``, sftp) there is no bucket to check."""
    fs, path = _filesystem(url, options)
    bucket = path.split("/")[0]
    if not bucket:
        return
    with _naming(url):
        try:
            fs.info(bucket)
        except FileNotFoundError:
            raise StoreError(f"{url}: bucket {bucket!r} does not exist") from None


def _tag(info: dict) -> str:
    """What changes when an object is rewritten: its ETag on S3, else its modification time."""
    for key in ("ETag", "etag", "mtime", "LastModified", "updated", "last_modified"):
        if info.get(key) is not None:
            return str(info[key]).strip('"')  # S3 quotes its ETags
    return ""


def _bag_signature(infos: list[dict], base: str) -> dict:
    """A bag directory's total size, and a digest of its objects' names and ETags."""
    tags = sorted((posixpath.relpath(i["name"], base), _tag(i)) for i in infos)
    digest = hashlib.sha256(json.dumps(tags).encode()).hexdigest()[:16]
    return {"size": sum(i["size"] for i in infos), "etag": digest}


def expand(pattern: str, options: dict) -> list[tuple[str, str, bool, dict]]:
    """The inputs a glob URL names, each as (URL, its path below the glob's fixed prefix, is a
    file, signature). As for local paths, an input is an object, or a "directory" (prefix)
    holding a metadata.yaml: a ROS 2 bag."""
    require(pattern, options)
    fs, path = _filesystem(pattern, options)
    fixed = []
    for p in path.split("/"):
        if glob.has_magic(p):
            break
        fixed.append(p)
    root = "/".join(fixed)
    if root == path:  # no magic: one input
        root = posixpath.dirname(path)
    inputs = []
    with _naming(pattern):
        found = fs.glob(path, detail=True)
        for name, info in sorted(found.items()):
            if TEMP_NAME.match(posixpath.basename(name)):
                continue  # an upload under way, or one a killed task left
            rel = posixpath.relpath(name, root)
            if info["type"] == "file":
                inputs.append((_url(fs, name), rel, True,
                               {"size": info["size"], "etag": _tag(info)}))
            elif fs.exists(f"{name}/metadata.yaml"):
                files = list(fs.find(name, detail=True).values())
                inputs.append((_url(fs, name), rel, False, _bag_signature(files, name)))
    return inputs


def exists(url: str, options: dict) -> bool:
    if not is_remote(url):
        return os.path.exists(url)
    fs, path = _filesystem(url, options)
    with _naming(url):
        return fs.exists(path)


def read_text(url: str, options: dict) -> str | None:
    """The object's text, or None when there is none."""
    fs, path = _filesystem(url, options)
    with _naming(url):
        try:
            return fs.cat_file(path).decode()
        except FileNotFoundError:
            return None


def download(url: str, dest_dir: str, options: dict) -> str:
    """Copies an input object, or every object of a bag directory, into ``dest_dir`` under its
    own name; returns the local path."""
    fs, path = _filesystem(url, options)
    local = os.path.join(dest_dir, posixpath.basename(path))
    with _naming(url):
        if fs.isdir(path):
            for src in fs.find(path):
                dst = os.path.join(local, *posixpath.relpath(src, path).split("/"))
                os.makedirs(os.path.dirname(dst), exist_ok=True)
                fs.get_file(src, dst)
        else:
            fs.get_file(path, local)
    return local


def _temp_key(path: str) -> str:
    parent, name = posixpath.split(path)
    return posixpath.join(parent, f".{name}.tmp-{uuid.uuid4().hex}")


def _remove_quietly(fs, path: str) -> None:
    """Best effort: a temporary key that cannot be removed now is removed by :func:`sweep`."""
    try:
        fs.rm_file(path)
    except Exception:  # noqa: BLE001 -- already gone, or the store is unreachable
        pass


def _publish(fs, path: str, size: int, write) -> None:
    """Makes the object ``path`` appear whole or not at all.

    ``write(tmp)`` writes the object to a temporary key beside the final one (unique per call, so
    a retried task never touches an earlier attempt's upload). Once that key holds all ``size``
    bytes it is copied to the final key and removed; whatever fails, the temporary key is removed
    too.

    What this relies on: S3 (and S3-compatible stores) make an object visible only when the
    request that creates it completes, a PutObject, a CompleteMultipartUpload or a CopyObject
    (s3fs's copy is a server-side CopyObject, or a multipart copy above 150 MiB): a reader gets the
    previous object or the new one, never a part. An interrupted upload to the temporary key
    leaves either nothing visible (an unfinished multipart upload) or a complete temporary object,
    never anything under the final key; and the final key is only ever written from an object
    whose size has been checked, by one server-side copy that does not depend on the worker.
    """
    tmp = _temp_key(path)
    try:
        write(tmp)
        uploaded = fs.info(tmp)["size"]
        if uploaded != size:
            raise OSError(f"uploaded {uploaded} of {size} bytes")
        fs.cp_file(tmp, path)
    finally:
        _remove_quietly(fs, tmp)


def upload(local: str, url: str, options: dict) -> None:
    """Uploads a local file to ``url`` atomically (see :func:`_publish`)."""
    fs, path = _filesystem(url, options)
    with _naming(url):
        _publish(fs, path, os.path.getsize(local), lambda tmp: fs.put_file(local, tmp))


def write_bytes(url: str, data: bytes, options: dict) -> None:
    """Writes ``data`` to ``url`` atomically (see :func:`_publish`)."""
    fs, path = _filesystem(url, options)
    with _naming(url):
        _publish(fs, path, len(data), lambda tmp: fs.pipe_file(tmp, data))


def sweep(urls: list[str], options: dict) -> int:
    """Removes the temporary keys of ``urls`` that failed uploads could not remove (a worker
    killed between its upload and its copy); returns how many."""
    by_dir: dict[str, set[str]] = {}
    for url in urls:
        parent, name = posixpath.split(url)
        by_dir.setdefault(parent, set()).add(name)
    removed = 0
    for parent, names in by_dir.items():
        fs, path = _filesystem(parent, options)
        with _naming(parent):
            try:
                listing = fs.ls(path, detail=False)
            except FileNotFoundError:
                continue
            for key in listing:
                m = TEMP_NAME.match(posixpath.basename(key))
                if m and m["name"] in names:
                    fs.rm_file(key)
                    removed += 1
    return removed
