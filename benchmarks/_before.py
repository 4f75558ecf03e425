"""The library's code at an earlier commit, for before/after benchmarks and their tests.

A benchmark that times a change against the code it replaced needs that code in the same run.
Rather than keeping copies of old library code in the repository, the "before" code is taken
from git history: :func:`tree_at` unpacks ``git archive <commit> repro`` into a temporary
folder (once per process and commit; removed at exit), which a child process can put first on
its ``PYTHONPATH`` (``benchmarks/bench_prepare.py`` prepares with it), and
:func:`import_before` imports one module file of that tree in this process under a distinct
name, beside today's ``repro`` (``sys.modules["repro..."]`` is never replaced; a module the old
code imports that has moved since is answered by a stand-in only while it is imported), so that
old functions can be called, or swapped in for today's with :func:`swapped`.

An old module imported this way runs its top-level code against today's ``repro``: its absolute
``repro.*`` imports resolve to today's modules (helpers it shares with today's code are today's;
the functions and classes it defines itself are the old ones).  A class it decorates with a
registering decorator would replace today's class in that registry, so the registries of
generators and protocols are restored after the import.

Without git history holding the commit (a source tarball without ``.git``, a shallow clone),
:class:`BeforeUnavailable` says so; benchmarks then report "after" only or stop, tests skip.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import importlib.util
import io
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: modules whose ``_REGISTRY`` an old module's class decorators would write to
_REGISTRIES = ("repro.models.base", "repro.eval.protocols")


class BeforeUnavailable(RuntimeError):
    """The "before" code cannot be had here: no git, no repository, or the commit not in it."""


def _git(*args: str) -> bytes:
    try:
        return subprocess.run(["git", "-C", str(REPO), *args], check=True,
                              capture_output=True).stdout
    except FileNotFoundError:
        raise BeforeUnavailable("git is not installed") from None
    except subprocess.CalledProcessError as e:
        msg = e.stderr.decode(errors="replace").strip().splitlines()
        raise BeforeUnavailable(f"git {args[0]}: "
                                f"{msg[-1] if msg else f'exit {e.returncode}'}") from None


@functools.cache
def resolve(commit: str) -> str:
    """The full hash of ``commit`` in this repository's history (BeforeUnavailable if the
    history is missing or does not hold it)."""
    if not commit:
        raise BeforeUnavailable("no commit given")
    try:
        return _git("rev-parse", "--verify", "--quiet", f"{commit}^{{commit}}").decode().strip()
    except BeforeUnavailable as e:
        raise BeforeUnavailable(f"commit {commit[:12]} is not in the git history of {REPO} "
                                f"({e}; a source tarball or a shallow clone lacks it)") from None


@functools.cache
def tree_at(commit: str, paths: tuple[str, ...] = ("repro",)) -> Path:
    """A temporary folder holding ``paths`` of the repository as they were at ``commit``
    (``git archive``); made once per process, commit and paths, removed when the process
    exits.  Put it first on a child's ``PYTHONPATH`` to run the old ``repro`` there."""
    sha = resolve(commit)
    tar = _git("archive", "--format=tar", sha, *paths)
    root = Path(tempfile.mkdtemp(prefix=f"before-{sha[:12]}-"))
    atexit.register(shutil.rmtree, root, ignore_errors=True)
    with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
        tf.extractall(root, filter="data")
    return root


def load_module(path: Path, name: str):
    """Import the module file ``path`` under ``name`` (registered in ``sys.modules``, where
    dataclasses and pickling look their module up); a name already imported is returned as
    it is, so an old module's top-level code runs once per process."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    try:
        spec.loader.exec_module(mod)
    except BaseException:
        del sys.modules[name]
        raise
    return mod


def moved_modules() -> dict:
    """{old module name: a stand-in module} for the library modules that have moved since the
    commits the benchmarks compare with, offering today's objects under the old names: issue
    30 moved ``repro.models.items`` (the item containers to :mod:`repro.data.action_items`,
    ``local_joints`` into :mod:`repro.models.marionet`; the same functions)."""
    import types

    from repro.data import action_items, contexts
    from repro.models.marionet import local_joints

    items = types.ModuleType("repro.models.items")
    for mod, names in ((action_items, ("ActionItems", "GeneratedItems", "ItemsConfig",
                                       "ITEMS_VERSION", "pad_last", "condition_items")),
                       (contexts, ("build_items", "items_from_windows", "in_place_classes",
                                   "next_tags"))):
        for n in names:
            setattr(items, n, getattr(mod, n))
    items.local_joints = local_joints
    return {"repro.models.items": items}


def import_before(commit: str, relpath: str, *, stand_ins=None):
    """The module file ``relpath`` (e.g. ``"repro/train/loop.py"``) as it was at ``commit``,
    imported under a name of its own (``_before_<hash>_repro_train_loop``) beside today's
    modules; today's generator and protocol registries are left as they were (module
    docstring).  ``stand_ins`` ({module name: module}; default :func:`moved_modules`) answer
    the old module's imports of modules that no longer exist under that name; they are in
    ``sys.modules`` only while it is imported, and never replace a module that exists."""
    sha = resolve(commit)
    root = tree_at(commit)
    path = root / relpath
    if not path.is_file():
        raise BeforeUnavailable(f"{relpath} does not exist at commit {sha[:12]}")
    name = f"_before_{sha[:12]}_" + relpath.removesuffix(".py").replace("/", "_")
    # the stand-ins first: building them imports today's modules, whose registrations must
    # survive the restore below
    stand_ins = moved_modules() if stand_ins is None else dict(stand_ins)
    saved = {m: dict(importlib.import_module(m)._REGISTRY) for m in _REGISTRIES}
    added = [m for m in stand_ins if m not in sys.modules]
    try:
        for m in added:
            sys.modules[m] = stand_ins[m]
        return load_module(path, name)
    finally:
        for m in added:
            sys.modules.pop(m, None)
        for m, reg in saved.items():
            sys.modules[m]._REGISTRY.clear()
            sys.modules[m]._REGISTRY.update(reg)


@contextlib.contextmanager
def swapped(*replacements: tuple[object, str, object]):
    """Within the block, ``setattr(owner, attr, value)`` for each ``(owner, attr, value)``;
    the previous values are put back on exit (also after an exception).  An attribute a
    class only inherits is deleted again, not copied onto the class."""
    saved = [(owner, attr, vars(owner).get(attr, _MISSING)) for owner, attr, _ in replacements]
    try:
        for owner, attr, value in replacements:
            setattr(owner, attr, value)
        yield
    finally:
        for owner, attr, value in reversed(saved):
            if value is _MISSING:
                delattr(owner, attr)
            else:
                setattr(owner, attr, value)


_MISSING = object()
