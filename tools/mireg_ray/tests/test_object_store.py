"""The Ray driver with inputs and outputs in an S3 bucket, against moto's S3 server
(``moto.server.ThreadedMotoServer``: the S3 HTTP API on 127.0.0.1, in this process): a run over
two logs and two bag directories whose outputs must hold the same poses as local runs, a re-run
that recomputes nothing, uploads that fail midway and leave no object behind, and the one-line
errors of a missing bucket, an unreachable endpoint and a glob that matches nothing.

    MIREG_BIN=target/debug/mireg tools/.venv-ray/bin/python -m pytest -q tools/mireg_ray/tests
"""

from __future__ import annotations

import io
import json
import os
import posixpath
import subprocess
import tempfile
from pathlib import Path

import fsspec
import pytest
from moto.server import ThreadedMotoServer

from mireg_ray import __main__ as cli
from mireg_ray import common, run, store

REPO = Path(__file__).resolve().parents[3]
FIXTURE = REPO / "fixtures" / "icl_livingroom1.mcap"
BAGS = REPO / "fixtures" / "bags"
# Input key (below s3://logs/in/) -> the local fixture it is a copy of.
INPUTS = {"day1/a.mcap": FIXTURE, "day2/b.mcap": FIXTURE,
          "bags/icl4_mcap": BAGS / "icl4_mcap", "bags/icl4_db3": BAGS / "icl4_db3"}
OUTPUTS = {"day1/a.mcap": "day1/a.mireg.mcap", "day2/b.mcap": "day2/b.mireg.mcap",
           "bags/icl4_mcap": "bags/icl4_mcap.mireg.mcap",
           "bags/icl4_db3": "bags/icl4_db3.mireg.mcap"}


@pytest.fixture(scope="module")
def s3():
    """(endpoint URL, a filesystem on it) with buckets ``logs`` (the inputs) and ``results``."""
    with pytest.MonkeyPatch.context() as mp:
        # moto accepts any credentials; these keep boto from looking for real ones.
        for k, v in {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing",
                     "AWS_DEFAULT_REGION": "us-east-1"}.items():
            mp.setenv(k, v)
        for k in ("AWS_ENDPOINT_URL", "AWS_ENDPOINT_URL_S3", "AWS_PROFILE"):
            mp.delenv(k, raising=False)
        server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
        server.start()
        try:
            host, port = server.get_host_and_port()
            endpoint = f"http://{host}:{port}"
            # No listing cache: the tests look at the bucket as the driver leaves it.
            fs = fsspec.filesystem("s3", endpoint_url=endpoint, use_listings_cache=False)
            fs.mkdir("logs")
            fs.mkdir("results")
            for key, src in INPUTS.items():
                files = [src] if src.is_file() else sorted(src.iterdir())
                for f in files:
                    dst = f"logs/in/{key}" + ("" if src.is_file() else f"/{f.name}")
                    fs.put_file(str(f), dst)
            yield endpoint, fs
        finally:
            server.stop()


def pose_bytes(data: bytes) -> list[bytes]:
    from mcap.reader import make_reader

    reader = make_reader(io.BytesIO(data))
    return [m.data for _, _, m in reader.iter_messages(topics=["/mireg/pose"])]


def local_poses(binary: str, log: Path, tmp: Path) -> list[bytes]:
    ref = tmp / f"{log.name}.ref.mcap"
    if not ref.exists():
        subprocess.run([binary, "register", str(log), "-o", str(ref), "--quiet", "--no-loops"],
                       check=True, env=dict(os.environ, RAYON_NUM_THREADS="1"))
    poses = pose_bytes(ref.read_bytes())
    assert poses
    return poses


def temp_keys(fs, bucket: str) -> list[str]:
    return [k for k in fs.find(bucket) if store.TEMP_NAME.match(posixpath.basename(k))]


def test_run_in_a_bucket_matches_local_runs_and_reruns_nothing(s3, tmp_path, binary, monkeypatch):
    endpoint, fs = s3
    out = "s3://results/out"
    # A temporary object a killed upload left behind: the run removes it.
    stale = f"results/out/day1/.a.mireg.mcap.tmp-{'0' * 32}"
    fs.pipe_file(stale, b"partial")
    args = ["run", "s3://logs/in/*/*", "--out", out, "--local-cpus", "2",
            "--storage-option", f"endpoint_url={endpoint}", "--", "--no-loops"]
    assert cli.main(args) == 0

    keys = sorted(fs.find("results"))
    assert keys == sorted([f"results/out/{o}" for o in OUTPUTS.values()]
                          + ["results/out/manifest.jsonl"]), keys
    lines = [json.loads(line) for line in fs.cat_file("results/out/manifest.jsonl").splitlines()]
    assert sorted(e["input"] for e in lines) == sorted(f"s3://logs/in/{k}" for k in INPUTS)
    for e in lines:
        key = e["input"].removeprefix("s3://logs/in/")
        assert e["status"] == "done", e
        assert e["output"] == e["summary"]["output"] == f"{out}/{OUTPUTS[key]}"
        assert set(e["signature"]) == {"size", "etag"}
        # The same poses, byte for byte, as a local run of the same input.
        local = local_poses(binary, INPUTS[key], tmp_path)
        assert pose_bytes(fs.cat_file(e["output"])) == local, key

    # A re-run recomputes nothing: no Ray at all.
    def no_ray(*_):
        raise AssertionError("a re-run with nothing to do started Ray")

    monkeypatch.setattr(common, "init_ray", no_ray)
    assert cli.main(args) == 0
    again = [json.loads(line) for line in fs.cat_file("results/out/manifest.jsonl").splitlines()]
    assert [e["status"] for e in again] == ["skipped"] * len(INPUTS)
    assert [e["summary"] for e in again] == [e["summary"] for e in lines]

    # A rewritten input has a new signature (its ETag), so a run would redo it and only it.
    fs.pipe_file("logs/in/day2/b.mcap", FIXTURE.read_bytes()[:-1] + b"\0")
    sigs = {url: sig for url, _, sig in run.plan("s3://logs/in/*/*", out,
                                                   {"endpoint_url": endpoint})}
    changed = [e["input"] for e in again if e["signature"] != sigs[e["input"]]]
    assert changed == ["s3://logs/in/day2/b.mcap"]


def test_a_failed_upload_or_run_leaves_no_object(s3, tmp_path, binary, monkeypatch):
    """The task body (without Ray) with the store's upload broken in three places, and with a
    log mireg cannot read: no final object, no temporary object, no local temporary file."""
    endpoint, fs = s3
    options = {"endpoint_url": endpoint}
    work = tmp_path / "worker_tmp"
    work.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(work))
    out = "s3://results/failing/icl4.mireg.mcap"

    def dies_midway(local, tmp, **_):  # an upload cut off after part of the object was written
        fs.pipe_file(tmp, Path(local).read_bytes()[:1000])
        raise ConnectionResetError("connection reset by peer")

    def short(local, tmp, **_):  # a store that silently kept part of the object
        fs.pipe_file(tmp, Path(local).read_bytes()[:1000])

    def copy_fails(*_, **__):
        raise ConnectionResetError("connection reset during copy")

    cases = [("put_file", dies_midway, "connection reset by peer"),
             ("put_file", short, "uploaded 1000 of"),
             ("cp_file", copy_fails, "connection reset during copy")]
    # The filesystem object (cached by fsspec) that the task's upload uses.
    task_fs = store._filesystem(out, options)[0]
    for attr, broken, message in cases:
        with monkeypatch.context() as m:
            m.setattr(task_fs, attr, broken)
            result = run.register_task(binary, "s3://logs/in/bags/icl4_mcap", out, [], 1, options)
        assert result["status"] == "failed" and message in result["error"], result
        assert out in result["error"]
        assert not fs.exists(out)
        assert temp_keys(fs, "results") == []
        assert list(work.iterdir()) == []

    # A log mireg cannot read: its error names the object, not the downloaded copy.
    corrupt = bytearray(FIXTURE.read_bytes())
    for i in range(len(corrupt) // 3, len(corrupt) // 3 + 64):
        corrupt[i] ^= 0x5A
    fs.pipe_file("logs/bad/corrupt.mcap", bytes(corrupt))
    result = run.register_task(binary, "s3://logs/bad/corrupt.mcap", out, [], 1, options)
    assert result["status"] == "failed"
    assert "s3://logs/bad/corrupt.mcap" in result["error"] and str(work) not in result["error"]
    assert not fs.exists(out) and temp_keys(fs, "results") == [] and list(work.iterdir()) == []

    # And the same task with nothing broken publishes the output.
    result = run.register_task(binary, "s3://logs/in/bags/icl4_mcap", out, [], 1, options)
    assert result["status"] == "done", result
    assert fs.exists(out) and temp_keys(fs, "results") == [] and list(work.iterdir()) == []


def test_store_errors_are_one_line_naming_the_url(s3, capsys, monkeypatch):
    endpoint, _ = s3

    def main(*args) -> tuple[int, str]:
        code = cli.main(["run", *args])
        captured = capsys.readouterr()
        return code, (captured.err + captured.out).strip()

    opt = ["--storage-option", f"endpoint_url={endpoint}"]
    code, text = main("s3://nosuchbucket/logs/*.mcap", "--out", "s3://results/x", *opt)
    assert code == 2 and text.startswith("error: s3://nosuchbucket/logs/*.mcap: bucket "
                                         "'nosuchbucket' does not exist"), text
    assert len(text.splitlines()) == 1
    code, text = main("s3://logs/in/*/*", "--out", "s3://nosuchbucket/out", *opt)
    assert code == 2
    assert text == "error: s3://nosuchbucket/out: bucket 'nosuchbucket' does not exist"
    code, text = main("s3://logs/nothing/*.mcap", "--out", "s3://results/x", *opt)
    assert code == 2 and text == "no input matches 's3://logs/nothing/*.mcap'"
    # The endpoint from the standard AWS_ENDPOINT_URL, without --storage-option.
    monkeypatch.setenv("AWS_ENDPOINT_URL", endpoint)
    code, text = main("s3://nosuchbucket/logs/*.mcap", "--out", "s3://results/x")
    assert code == 2 and "bucket 'nosuchbucket' does not exist" in text, text
    monkeypatch.delenv("AWS_ENDPOINT_URL")
    # Nothing listens on port 1; one attempt, not botocore's default retries.
    code, text = main("s3://logs/in/*.mcap", "--out", "s3://results/x",
                      "--storage-option", "endpoint_url=http://127.0.0.1:1",
                      "--storage-option", 'config_kwargs={"retries": {"max_attempts": 1}}')
    assert code == 2 and text.startswith("error: s3://results/x: EndpointConnectionError: "
                                         "Could not connect to the endpoint URL"), text
    assert len(text.splitlines()) == 1
