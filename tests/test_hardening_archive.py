"""Issue 16: a data-set source's files are size-capped before they are read.

A 46 KB ``.tar.xz`` holding one 300 MB ``.bvh`` used ~1 GB of memory before it was refused.
Now the tar header's ``size`` (a folder file's ``stat``) is checked against
``sources.MAX_MEMBER_BYTES`` / ``MAX_SOURCE_BYTES`` before a byte of the member is read.
"""

from __future__ import annotations

import dataclasses
import io
import os
import subprocess
import sys
import tarfile
import tracemalloc
from pathlib import Path

import pytest
from test_bandai import TOY_CARD, cache_listing, write_toy

from repro.data import bandai, sources
from repro.data.bandai import prepare_bandai2
from repro.data.cache import dataset_dir
from repro.errors import DataError

REPO = Path(__file__).resolve().parents[1]
BIG = "dataset/data/dataset-2_walk_active_099.bvh"


class Zeros(io.RawIOBase):
    """``n`` zero bytes, produced as read (nothing that size is ever held in memory)."""

    def __init__(self, n: int):
        self.left = n

    def readable(self):
        return True

    def readinto(self, b):
        k = min(len(b), self.left)
        b[:k] = bytes(k)
        self.left -= k
        return k


def add_zeros(tf: tarfile.TarFile, name: str, size: int) -> None:
    ti = tarfile.TarInfo(name)
    ti.size = size
    tf.addfile(ti, io.BufferedReader(Zeros(size)))


def toy_archive(tmp_path: Path, big: int | None = None, big_first: bool = True) -> Path:
    """The toy Bandai-shaped set as a .tar.xz, with a ``big``-byte zero .bvh member."""
    write_toy(tmp_path / "src")
    arc = tmp_path / "toy.tar.xz"
    # preset 0: a 256 KiB xz dictionary, so the decoder's own memory stays small
    with tarfile.open(arc, "w:xz", preset=0) as tf:
        if big is not None and big_first:
            add_zeros(tf, BIG, big)
        tf.add(tmp_path / "src", arcname="dataset")
        if big is not None and not big_first:
            add_zeros(tf, BIG, big)
    return arc


def test_caps_are_stated():
    assert sources.MAX_MEMBER_BYTES == 64 * 1024 ** 2
    assert sources.MAX_SOURCE_BYTES == 4 * 1024 ** 3
    # 100 times the largest real Bandai-2 clip (615 KB) and 8 times the whole archive (515 MB)
    assert sources.MAX_MEMBER_BYTES > 100 * 614_934 and sources.MAX_SOURCE_BYTES > 8 * 514_694_070
    # still importable from the module that held them
    assert (bandai.MAX_MEMBER_BYTES, bandai.MAX_SOURCE_BYTES, bandai.MAX_TAR_HEADER_BYTES) == (
        sources.MAX_MEMBER_BYTES, sources.MAX_SOURCE_BYTES, sources.MAX_TAR_HEADER_BYTES)


@pytest.mark.parametrize("big_first", [True, False])
def test_member_over_the_cap_is_refused_before_it_is_read(tmp_path, monkeypatch, big_first):
    arc = toy_archive(tmp_path, big=4 * 1024 ** 2, big_first=big_first)
    assert arc.stat().st_size < 64 * 1024  # a 4 MiB member compresses to almost nothing
    monkeypatch.setattr(sources, "MAX_MEMBER_BYTES", 1024 ** 2)
    tracemalloc.start()
    try:
        with pytest.raises(DataError) as e:
            for _ in sources.iter_source(arc):
                pass
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    msg = str(e.value)
    assert msg.startswith(f"{arc}: {BIG} is 4.0 MiB, over the 1.0 MiB cap on one file"), msg
    assert "MAX_MEMBER_BYTES" in msg
    assert peak < 2 * 1024 ** 2, peak  # the 4 MiB member was neither read nor inflated


def test_total_over_the_cap_is_refused(tmp_path, monkeypatch):
    arc = toy_archive(tmp_path)
    total = sum(m.size for m in tarfile.open(arc) if m.isfile())
    monkeypatch.setattr(sources, "MAX_SOURCE_BYTES", total - 1)
    with pytest.raises(DataError, match=r"add up to .* over the .* cap on a source "
                                        r"\(sources.MAX_SOURCE_BYTES\)") as e:
        prepare_bandai2(arc, card=TOY_CARD, workers=0)
    assert str(e.value).startswith(f"{arc}: the files up to dataset/")
    monkeypatch.setattr(sources, "MAX_SOURCE_BYTES", total)
    assert prepare_bandai2(arc, card=TOY_CARD, workers=0).clips == 8  # exactly at the cap: fine


def test_members_not_read_still_count_towards_the_total(tmp_path, monkeypatch):
    # A stream must decompress a member even to skip it, so a huge README counts too.
    write_toy(tmp_path / "src")
    arc = tmp_path / "toy.tar.xz"
    with tarfile.open(arc, "w:xz") as tf:
        add_zeros(tf, "dataset/README", 3 * 1024 ** 2)
        tf.add(tmp_path / "src", arcname="dataset")
    monkeypatch.setattr(sources, "MAX_MEMBER_BYTES", 1024 ** 2)  # not read: no per-file cap
    monkeypatch.setattr(sources, "MAX_SOURCE_BYTES", 2 * 1024 ** 2)
    with pytest.raises(DataError, match="the files up to dataset/README add up to 3.0 MiB"):
        prepare_bandai2(arc, card=TOY_CARD, workers=0)


def test_folder_file_over_the_cap_is_refused_by_stat(tmp_path, monkeypatch):
    write_toy(tmp_path / "src")
    big = tmp_path / "src" / "data" / "dataset-2_walk_active_099.bvh"
    with open(big, "wb") as f:
        f.truncate(2 * 1024 ** 2)  # sparse: nothing written
    monkeypatch.setattr(sources, "MAX_MEMBER_BYTES", 1024 ** 2)
    with pytest.raises(DataError) as e:
        prepare_bandai2(tmp_path / "src", card=TOY_CARD, workers=0)
    assert str(e.value).startswith(f"{tmp_path / 'src'}: data/{big.name} is 2.0 MiB, over the "
                                   "1.0 MiB cap on one file")


def test_huge_extension_header_is_refused(tmp_path, monkeypatch):
    arc = tmp_path / "long.tar.xz"
    write_toy(tmp_path / "src")
    with tarfile.open(arc, "w:xz", format=tarfile.PAX_FORMAT) as tf:
        tf.add(tmp_path / "src", arcname="dataset/" + "x" * 4000)  # names in pax headers
    monkeypatch.setattr(sources, "MAX_TAR_HEADER_BYTES", 1024)
    with pytest.raises(DataError, match=r"a tar extension header of .* over the .* cap"):
        prepare_bandai2(arc, card=TOY_CARD, workers=0)


def test_cli_300_mb_member_one_line_exit_2_cache_kept(tmp_path):
    """The issue's case with the real caps, through the CLI: a header claiming a 300 MB .bvh
    (the archive is a few KB: the member's data is never there, and never needed)."""
    card = dataclasses.replace(TOY_CARD, name="bandai2")
    write_toy(tmp_path / "good", card=card)
    prepare_bandai2(tmp_path / "good", card=card, workers=0)
    root = dataset_dir("bandai2")
    before = cache_listing(root)
    arc = tmp_path / "bomb.tar.xz"
    with tarfile.open(arc, "w:xz") as tf:
        ti = tarfile.TarInfo(BIG)
        ti.size = 300 * 1024 ** 2
        tf.addfile(ti)  # the header alone
    assert arc.stat().st_size < 4096
    r = subprocess.run([sys.executable, "-m", "cli.main", "data", "prepare", "bandai2",
                        "--source", str(arc), "--force"], capture_output=True, text=True,
                       cwd=REPO, env=dict(os.environ), timeout=300)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert lines[0] == (f"repro: error: {arc}: {BIG} is 300.0 MiB, over the 64.0 MiB cap on "
                        "one file (sources.MAX_MEMBER_BYTES); not read"), lines[0]
    assert cache_listing(root) == before  # the prepared cache is untouched
