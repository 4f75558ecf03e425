"""``repro export``: stored samples out of the harness, as BVH (Blender, Maya, MotionBuilder)
or as ``.npz`` joint positions.

What is exported is chosen like a table cell narrows down: a table's run (default: the newest
finished one), optionally one ``row``, one ``replicate`` (default 0; ``all`` for every one),
one ``item`` (a single-action test item, or a multi-action test sequence; default: all).  One
file per (row, replicate, item), named ``<row>-r<replicate>-item<i>.bvh`` (``-seq<s>`` for a
test sequence), plus ``export.json`` saying what each file holds (table, run, band, tag(s),
frames, seed).

- **single action**: the generated action, its valid frames only (``lengths``), in the world
  frame the protocol measured it in;
- **multi action**: the whole generated chain of a test sequence, its actions one after
  another (each cut to its duration), so the file plays the sequence as the scoring saw it;
- **MultiAct single step** (``multiact_conditioned``, ``transition``; ``item``: a test pair):
  the generated ``[T̂, Ŝ_c]`` (``l_t + l_c`` frames; ACTOR: ``Ŝ_c`` only) in the world frame it
  was made in, continuing its ``S_p``.  ``S_p`` is not in the file (the real one is a test
  pair's, a generated one is not stored); the meta gives ``prev_tag``, ``transition_frames``
  and ``action_frames``;
- **MultiAct long term** (``long_term``; ``item``: a label sequence): the whole generated chain,
  step after step, every action but the last cut to the frames the next step continued from
  (``prev_trim`` fewer, :func:`repro.report.pair_strips.chain_parts`); the meta gives the
  steps' ``tags``, ``frames`` and ``transition_frames``.

A BVH is written on the samples' skeleton (the data set's, :mod:`repro.data.bvh_write`:
centimetres, ZXY Euler channels); ``dummy_root`` adds the all-zero root the Bandai files carry,
so an export can be read back as data.  An ``.npz`` holds ``joints`` (T, J, 3) metres,
``root`` (T, 3), ``rot6d`` (T, J, 6), ``names``, ``parents``, ``fps`` and the same meta.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from repro.errors import ConfigError, DataError

FORMATS = ("bvh", "npz")


def _multiact_pieces(band, g, item: int | None):
    """:func:`_pieces` of MultiAct samples (module docstring)."""
    names = band.items.label_names
    if g.n_sequences:
        from repro.report.pair_strips import chain_parts

        S, N = g.n_sequences, g.n_steps
        trim = int(band.protocol.params.prev_trim)
        for s in range(S) if item is None else [item]:
            if not 0 <= s < S:
                raise ConfigError(f"--item {s}: the long-term plan has label sequences "
                                  f"0..{S - 1}")
            parts = chain_parts(g, s, N, trim)
            yield f"seq{s}", [(i, lt + lc) for i, lt, lc in parts], {
                "sequence": s, "tags": [names[int(g.labels[i])] for i, _, _ in parts],
                "frames": [lt + lc for _, lt, lc in parts],
                "transition_frames": [lt for _, lt, _ in parts], "prev_trim": trim}
        return
    items = band.items
    N = len(g)
    for i in range(N) if item is None else [item]:
        if not 0 <= i < N:
            raise ConfigError(f"--item {i}: the test pairs are 0..{N - 1}")
        lt, lc = int(g.l_t[i]), int(g.l_c[i])
        yield f"item{i}", [(i, lt + lc)], {
            "item": i, "tag": names[int(g.labels[i])],
            "prev_tag": names[int(items.prev_labels[i])], "frames": lt + lc,
            "transition_frames": lt, "action_frames": lc}


def _pieces(band, g, item: int | None):
    """(stem suffix, motion slices, meta) of every exported item of one row's samples."""
    if hasattr(g, "items_key"):  # MultiAct's samples (MultiActSamples)
        yield from _multiact_pieces(band, g, item)
    elif not hasattr(g, "motion"):  # ODMO's joint-position windows (OdmoSamples, LatentSamples)
        N, names = len(g), band.items.train.label_names
        for i in (range(N) if item is None else [item]):
            if not 0 <= i < N:
                raise ConfigError(f"--item {i}: the samples are 0..{N - 1}")
            yield f"item{i}", [(i, int(g.joints.shape[1]))], {
                "item": i, "tag": names[int(g.labels[i])], "frames": int(g.joints.shape[1])}
    elif band.is_sequence:
        S, L = g.n_sequences, g.n_actions
        which = range(S) if item is None else [item]
        for s in which:
            if not 0 <= s < S:
                raise ConfigError(f"--item {s}: the test set has sequences 0..{S - 1}")
            idx = [s * L + j for j in range(L)]
            lens = [int(g.lengths[i]) for i in idx]
            tags = [band.items.label_names[int(g.labels[i])] for i in idx]
            yield f"seq{s}", [(i, n) for i, n in zip(idx, lens)], {
                "sequence": s, "tags": tags, "frames": lens}
    else:
        N = len(g)
        which = range(N) if item is None else [item]
        for i in which:
            if not 0 <= i < N:
                raise ConfigError(f"--item {i}: the test items are 0..{N - 1}")
            n = int(g.lengths[i])
            yield f"item{i}", [(i, n)], {"item": i, "tag": band.items.label_names[int(g.labels[i])],
                                         "frames": n}


def _chosen_rows(rs, *, row: str | None, replicate: int | str, band: int | None) -> list:
    """The generated rows of run samples ``rs`` that ``band``, ``row`` and ``replicate`` choose
    (:func:`export_samples`), each choice checked; an error when none of them is available."""
    if band is not None and not 0 <= band < len(rs.bands):
        raise ConfigError(f"--band {band}: {rs.spec.id} has bands 0..{len(rs.bands) - 1} "
                          "(repro export --list shows them)")
    rows = [r for b in rs.bands for r in b.rows if band is None or b.index == band]
    if row is not None:
        ids = sorted({r.row_id for r in rows})
        if row not in ids:
            from repro.specs.names import suggest

            raise ConfigError(f"{rs.spec.id} has no generated row {row!r}"
                              f"{suggest(row, ids)}; rows with samples: {', '.join(ids)}")
        rows = [r for r in rows if r.row_id == row]
    if replicate != "all":
        reps = sorted({r.replicate for r in rows})
        if int(replicate) not in reps:
            raise ConfigError(f"--replicate {replicate}: the run has replicates "
                              f"{', '.join(map(str, reps))}")
        rows = [r for r in rows if r.replicate == int(replicate)]
    unavailable = [r for r in rows if not r.available]
    if unavailable and len(unavailable) == len(rows):
        raise ConfigError(f"{rs.spec.id} run {rs.run_id}: {unavailable[0].row_id}: "
                          f"{unavailable[0].reason}")
    return rows


def _loaded_pieces(rs, rows: list, item: int | None, fmt: str, record: dict) -> list:
    """Read the samples of every available row in ``rows`` (an unavailable one is noted in
    ``record["skipped"]``); returns (row, band, samples, *piece) of every item to export, each
    :func:`_pieces` piece (``item`` checked there)."""
    todo = []
    for r in rows:
        if not r.available:
            record.setdefault("skipped", []).append({"row": r.row_id, "reason": r.reason})
            continue
        b = rs.bands[r.band]
        try:
            g = b.load(r)
        except DataError as e:
            raise DataError(f"{rs.spec.id} run {rs.run_id}: row {r.row_id!r}: {e}") from None
        if fmt == "bvh" and not hasattr(g, "motion"):
            raise ConfigError(f"{rs.spec.id}: the samples of {b.protocol_id!r} are joint "
                              "positions only (ODMO's xyz windows); BVH needs rotations: use "
                              "--format npz")
        todo += [(r, b, g, *piece) for piece in _pieces(b, g, item)]  # checks `item`
    return todo


def _write_npz(rs, out: Path, name: str, sk, fps: float, r, meta: dict, **arrays) -> None:
    """Write ``arrays`` with the skeleton's names and parents, ``fps`` and the meta of row
    ``r`` as the ``.npz`` ``out / name``."""
    from repro.store.atomic import write_output

    buf = io.BytesIO()
    np.savez_compressed(
        buf, **arrays, names=np.array(sk.names), parents=np.array(sk.parents, dtype=np.int64),
        fps=np.float64(fps), meta=np.array(json.dumps(
            {"table": rs.spec.id, "run": rs.run_id, "row": r.row_id, **meta}, sort_keys=True)))
    write_output(out / name, buf.getvalue())


def _write_piece(rs, out: Path, stem: str, r, b, g, parts, meta: dict, *, fmt: str,
                 dummy_root: bool) -> tuple[str, float]:
    """Write one exported item (motion slices ``parts`` of samples ``g``) as ``stem`` plus
    the format's suffix in ``out``; returns the file's name and its frame rate."""
    import torch

    from repro.data.bvh_write import write_bvh

    if not hasattr(g, "motion"):  # joint positions only (ODMO's windows): npz
        (i, n), = parts
        name, fps = f"{stem}.npz", g.fps
        _write_npz(rs, out, name, b.items.train.skeleton, fps, r, meta,
                   joints=np.asarray(g.joints[i, :n], np.float64))
        return name, fps
    m = g.motion
    sk, fps = m.skeleton, m.fps
    root = torch.cat([m.root[i, :n] for i, n in parts]).double()
    rot6d = torch.cat([m.rot6d[i, :n] for i, n in parts])
    one = m.replace(root=root[None], rot6d=rot6d[None])
    if fmt == "bvh":
        from repro.data.bandai import DUMMY_ROOT

        name = f"{stem}.bvh"
        try:  # written beside the name and renamed: a link there is replaced
            write_bvh(out / name, sk, root.numpy(), one.rotmats()[0].double().numpy(),
                      fps, dummy_root=DUMMY_ROOT if dummy_root else None)
        except OSError as e:
            raise ConfigError(f"cannot write {str(out / name)!r}: "
                              f"{e.strerror or e}") from None
    else:
        name = f"{stem}.npz"
        _write_npz(rs, out, name, sk, fps, r, meta, joints=one.joints()[0].double().numpy(),
                   root=root.numpy(), rot6d=rot6d.double().numpy())
    return name, fps


def export_samples(rs, out: str | Path, *, row: str | None = None,
                   replicate: int | str = 0, item: int | None = None, fmt: str = "bvh",
                   dummy_root: bool = False, band: int | None = None) -> dict:
    """Write the chosen samples of a run (:func:`repro.engine.run_samples.run_samples`) into
    the folder ``out``; returns the ``export.json`` record.  Every choice is checked (and every
    chosen sample read) before the first file is written, so a bad ``item`` writes nothing.
    ``band``: only that band of the table (``--list`` shows them; an ``item`` is a test item
    in a single-action band and a test sequence in a multi-action one)."""
    from repro.store.atomic import output_dir, write_output

    if fmt not in FORMATS:
        raise ConfigError(f"unknown export format {fmt!r} (choose from {', '.join(FORMATS)})")
    rows = _chosen_rows(rs, row=row, replicate=replicate, band=band)
    multi_band = len({r.band for r in rows}) > 1
    record = {"schema": 1, "table": rs.spec.id, "run": rs.run_id, "format": fmt, "files": []}
    todo = _loaded_pieces(rs, rows, item, fmt, record)
    out = output_dir(out)  # '' (the current folder), a file, a device: one error line
    for r, b, g, suffix, parts, meta in todo:
        stem = f"{r.row_id}{f'-band{r.band}' if multi_band else ''}-r{r.replicate}-{suffix}"
        name, fps = _write_piece(rs, out, stem, r, b, g, parts, meta, fmt=fmt,
                                 dummy_root=dummy_root)
        record["files"].append({"file": name, "row": r.row_id, "band": r.band,
                                "protocol": b.protocol_id, "replicate": r.replicate,
                                "seed": r.seed, "fps": fps, **meta})
    write_output(out / "export.json", json.dumps(record, indent=1, sort_keys=True) + "\n")
    return record
