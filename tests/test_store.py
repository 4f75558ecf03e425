"""Content-addressed store: atomic publish, verified reads, quarantine + rebuild, file locks
across real processes, gc, and the `repro cache` commands."""

from __future__ import annotations

import json
import multiprocessing
import os
import stat
import time
from pathlib import Path

import pytest

from repro.keys import content_key, sha256_file
from repro.store.atomic import utc_now
from repro.store.object_files import MANIFEST
from repro.store.objects import Store


def _key(i) -> str:
    return content_key({"test-object": i})


def _write_payload(out: Path) -> None:
    (out / "a.txt").write_text("alpha\n")
    (out / "sub").mkdir()
    (out / "sub" / "b.bin").write_bytes(bytes(range(256)) * 4)


def _objects(store: Store) -> list[Path]:
    return sorted(p for p in store.objects_dir.glob("*/*") if p.is_dir())


def test_compute_publishes_once_with_manifest_and_read_only_files():
    store = Store()
    k = _key(1)
    assert not store.has(k) and store.get(k) is None
    calls = []

    def fn(out):
        calls.append(out)
        _write_payload(out)

    obj = store.compute(k, "demo", fn, meta={"label": "x"})
    assert obj.hit is False and obj.kind == "demo" and obj.meta == {"label": "x"}
    assert sorted(obj.files) == ["a.txt", "sub/b.bin"]
    assert obj.files["sub/b.bin"] == {"sha256": sha256_file(obj.file("sub/b.bin")), "size": 1024}
    assert obj.read_text("a.txt") == "alpha\n"
    man = json.loads((obj.path / MANIFEST).read_text())
    assert man["schema"] == 1 and man["key"] == k and man["kind"] == "demo"
    mode = stat.S_IMODE(obj.file("a.txt").stat().st_mode)
    assert mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH) == 0
    # second call is a hit; fn is not called again
    again = store.compute(k, "demo", fn)
    assert again.hit is True and len(calls) == 1
    assert store.has(k) and _objects(store) == [store.object_dir(k)]
    assert not list(store.objects_dir.glob("*/.tmp-*"))
    with pytest.raises(KeyError, match="no file"):
        obj.file("missing.txt")


def test_put_copies_a_folder_and_keys_are_validated(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    _write_payload(src)
    store = Store()
    obj = store.put(_key(2), src, "copied")
    assert obj.read_bytes("sub/b.bin") == (src / "sub" / "b.bin").read_bytes()
    assert store.put(_key(2), src, "copied").hit
    with pytest.raises(ValueError, match="64 lowercase hex"):
        store.get("abc")
    with pytest.raises(ValueError, match="reserved"):
        store.compute(_key(3), "bad", lambda out: (out / MANIFEST).write_text("{}"))
    assert not store.has(_key(3))


@pytest.mark.parametrize("damage", ["flip_byte", "truncate", "delete", "extra", "manifest"])
def test_corrupt_object_is_reported_quarantined_and_rebuilt(damage, caplog):
    store = Store()
    k = _key(("corrupt", damage))
    obj = store.compute(k, "demo", _write_payload)
    target = obj.file("sub/b.bin")
    os.chmod(target, 0o644)
    if damage == "flip_byte":
        data = bytearray(target.read_bytes())
        data[100] ^= 0xFF
        target.write_bytes(bytes(data))
    elif damage == "truncate":
        target.write_bytes(target.read_bytes()[:-1])
    elif damage == "delete":
        target.unlink()
    elif damage == "extra":
        (obj.path / "intruder.txt").write_text("?")
    else:
        (obj.path / MANIFEST).write_text("{not json")
    with caplog.at_level("WARNING", logger="repro.store"):
        assert store.get(k) is None
    assert any(k in r.getMessage() and "corrupt" in r.getMessage() for r in caplog.records)
    assert len(store.corrupt) == 1 and store.corrupt[0].key == k
    q = store.corrupt[0].quarantined_to
    assert q is not None and q.parent == store.quarantine_dir and (q / "REASON.txt").exists()
    assert not store.has(k)
    rebuilt = store.compute(k, "demo", _write_payload)
    assert rebuilt.hit is False
    assert store.get(k).read_bytes("sub/b.bin") == bytes(range(256)) * 4


def test_failed_or_interrupted_computation_leaves_no_object_but_keeps_scratch():
    store = Store()
    k = _key("interrupt")

    def fn(out):
        (store.scratch(k) / "ckpt.txt").write_text("step 3")
        (out / "partial.txt").write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        store.compute(k, "demo", fn)
    assert not store.has(k)
    assert not list(store.objects_dir.glob("*/.tmp-*"))
    assert (store.scratch(k) / "ckpt.txt").read_text() == "step 3"

    def resume(out):
        (out / "final.txt").write_text((store.scratch(k) / "ckpt.txt").read_text())

    assert store.compute(k, "demo", resume).read_text("final.txt") == "step 3"
    assert not (store.root / "scratch" / k).exists()  # removed once published


def test_verify_rehashes_everything_and_stamps_skip_big_files_in_get():
    store = Store(stamp_min_bytes=512)  # make b.bin (1 KiB) a "big" file
    k = _key("stamps")
    obj = store.compute(k, "demo", _write_payload)
    assert store.stamp_path(k).exists()
    target = obj.file("sub/b.bin")
    st = target.stat()
    os.chmod(target, 0o644)
    data = bytearray(target.read_bytes())
    data[0] ^= 1
    target.write_bytes(bytes(data))
    os.chmod(target, 0o444)
    # same size, inode and mtime as when verified: get() trusts the stamp ...
    os.utime(target, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert store.get(k) is not None
    # ... verify() never does
    rep = store.verify()
    assert rep.ok == [] and [c.key for c in rep.corrupt] == [k]
    assert not store.has(k)
    # a touched file (new mtime) is re-hashed by get()
    k2 = _key("stamps-2")
    o2 = store.compute(k2, "demo", _write_payload)
    t2 = o2.file("sub/b.bin")
    os.chmod(t2, 0o644)
    t2.write_bytes(bytes(data))
    assert store.get(k2) is None


def _proc_compute(root: str, key: str, gate: str, out_q) -> None:
    store = Store(root)
    gate_dir = Path(gate)

    def fn(out):
        with open(gate_dir / "calls.log", "a") as f:
            f.write(f"{os.getpid()}\n")
        (gate_dir / "started").touch()
        deadline = time.time() + 60
        while not (gate_dir / "release").exists() and time.time() < deadline:
            time.sleep(0.02)
        (out / "payload.bin").write_bytes(key.encode() * 100)

    obj = store.compute(key, "demo", fn)
    out_q.put((os.getpid(), obj.hit, obj.read_bytes("payload.bin")))


def test_two_processes_compute_one_key_once(tmp_path):
    """One process computes (and is held mid-computation); the second blocks on the key's lock,
    then reads the first one's object: one computation, identical bytes, one object."""
    store = Store()
    k = _key("concurrent")
    ctx = multiprocessing.get_context("spawn")
    q = ctx.Queue()
    first = ctx.Process(target=_proc_compute, args=(str(store.root), k, str(tmp_path), q))
    first.start()
    deadline = time.time() + 60
    while not (tmp_path / "started").exists():
        assert time.time() < deadline and first.is_alive()
        time.sleep(0.02)
    second = ctx.Process(target=_proc_compute, args=(str(store.root), k, str(tmp_path), q))
    second.start()
    time.sleep(1.0)  # the second process starts and blocks on the lock
    assert q.empty()
    (tmp_path / "release").touch()
    results = [q.get(timeout=60) for _ in range(2)]
    for p in (first, second):
        p.join(timeout=30)
        assert p.exitcode == 0
    assert len((tmp_path / "calls.log").read_text().split()) == 1  # exactly one computation
    by_pid = {pid: (hit, data) for pid, hit, data in results}
    assert by_pid[first.pid][0] is False and by_pid[second.pid][0] is True
    assert by_pid[first.pid][1] == by_pid[second.pid][1] == k.encode() * 100
    assert _objects(store) == [store.object_dir(k)]
    assert not list(store.objects_dir.glob("*/.tmp-*"))


def test_gc_keeps_referenced_and_locked_objects_and_removes_stale_temp():
    store = Store()
    keep, drop, busy = _key("keep"), _key("drop"), _key("busy")
    for k in (keep, drop, busy):
        store.compute(k, "demo", _write_payload)
    stale = store.objects_dir / drop[:2] / f".tmp-{drop}-999999-deadbeef"
    stale.mkdir()
    (stale / "junk").write_text("x")
    (store.scratch(keep) / "leftover").write_text("x")  # scratch of a published key
    (store.scratch(_key("unfinished")) / "ckpt").write_text("x")
    dry = store.gc({keep}, dry_run=True)
    assert {o.key for o in dry.objects} == {drop, busy} and store.has(drop) and stale.exists()
    from filelock import FileLock

    other = FileLock(str(store.lock_path(busy)))  # as if another process were computing it
    other.acquire()
    try:
        rep = store.gc({keep})
    finally:
        other.release()
    assert {o.key for o in rep.objects} == {drop} and rep.kept_locked == [busy]
    assert store.has(keep) and store.has(busy) and not store.has(drop)
    assert not stale.exists()
    assert [p.name for p in rep.scratch_dirs] == [keep]
    assert (store.root / "scratch" / _key("unfinished")).exists()
    rep2 = store.gc({keep, busy}, include_scratch=True)
    assert [p.name for p in rep2.scratch_dirs] == [_key("unfinished")]


def test_gc_keeps_objects_created_during_a_live_run():
    store = Store()
    old = _key("old")
    store.compute(old, "demo", _write_payload)
    time.sleep(0.01)
    cutoff = utc_now()  # a run started here and is still going
    new = _key("new")
    store.compute(new, "demo", _write_payload)
    rep = store.gc(set(), keep_created_after=cutoff)
    assert [o.key for o in rep.objects] == [old] and store.has(new)


def test_cache_cli_ls_verify_gc(capsys):
    from cli.main import main

    store = Store()
    k = store.compute(_key("cli"), "demo", _write_payload, meta={"label": "train/x"}).key
    assert main(["cache", "ls", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [(r["key"], r["kind"], r["label"], r["size"]) for r in rows] == [
        (k, "demo", "train/x", 6 + 1024)]
    assert main(["cache", "ls"]) == 0
    assert "train/x" in capsys.readouterr().out
    assert main(["cache", "verify"]) == 0
    assert "1 objects verified, 0 corrupt" in capsys.readouterr().out
    f = store.object_dir(k) / "a.txt"
    os.chmod(f, 0o644)
    f.write_text("ALPHA\n")
    assert main(["cache", "verify", "--json"]) == 1
    out = json.loads(capsys.readouterr().out)
    assert out["ok"] == 0 and out["corrupt"][0]["key"] == k
    assert "sha256 mismatch" in out["corrupt"][0]["problem"]
    store.compute(_key("cli2"), "demo", _write_payload)
    assert main(["cache", "gc", "--dry-run", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["dry_run"] and len(out["objects"]) == 1 and len(out["quarantine_dirs"]) == 1
    assert store.has(_key("cli2"))
    assert main(["cache", "gc"]) == 0
    assert "removed 1 objects" in capsys.readouterr().out
    assert store.keys() == []
