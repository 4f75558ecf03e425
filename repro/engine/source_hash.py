"""The hash of the source code that implements a job (issue 4, item 3).

``source_hash("repro.models.marionet")`` is sha256 (via :func:`repro.keys.content_key`) over
the sorted list of ``[module name, sha256 of the module file's bytes]`` for the module and every
module it imports, transitively, that is

- in the ``repro`` package, or
- in the same top-level package as the root module (so a job implemented outside ``repro``,
  e.g. a plug-in or a test module, still covers its own helpers),

together with the parent packages of each (their ``__init__.py`` runs on import).  Imports are
read with :mod:`ast` without executing anything: ``import a.b``, ``from a import b`` (``a.b``
counts when it is a submodule), relative imports, and imports inside functions (the project
imports heavy libraries lazily) all count; so do imports under ``if TYPE_CHECKING`` (a
harmless over-approximation).  Third-party libraries are not hashed: their versions are in the
run record.

Results are cached per process (:func:`clear_source_cache` empties the cache): a process runs
the code it imported, so its keys describe that code.  What each file imports is also kept
between processes, keyed by the module name and the sha256 of the file's bytes (so an entry
never goes stale; the file also names its schema and the reader that wrote it, and anything
else is a miss), in ``<REPRO_HOME>/cache/source-imports.json`` (:data:`IMPORTS_CACHE`):
parsing the ~400 files a table's keys cover was most of a fully cached ``repro plan`` (issue
31); every file is still read and hashed.
"""

from __future__ import annotations

import ast
import importlib.machinery
import importlib.util
import json
import os
import sys
from functools import lru_cache
from pathlib import Path

from repro.errors import ConfigError
from repro.keys import content_key, sha256_file

ROOT_PACKAGE = "repro"
#: the file under ``REPRO_HOME`` holding each parsed file's imports (module docstring)
IMPORTS_CACHE = Path("cache") / "source-imports.json"
#: at most this many entries: past it, a write keeps only the entries this process used
IMPORTS_CACHE_MAX = 4000
#: the cache file's layout: ``{"schema": 1, "reader": <sha256 of this module>, "entries": {…}}``
IMPORTS_CACHE_SCHEMA = 1

_parsed: dict[str, list[str]] | None = None  # IMPORTS_CACHE's entries, read on first use
_parsed_used: set[str] = set()
_parsed_dirty = False


def _find_spec(name: str):
    """The module spec of ``name`` found without importing anything (None if not found)."""
    mod = sys.modules.get(name)
    spec = getattr(mod, "__spec__", None) if mod is not None else None
    if spec is not None and name != "__main__":
        return spec
    parent, _, _ = name.rpartition(".")
    if not parent:
        spec = importlib.machinery.PathFinder.find_spec(name)
        if spec is None:
            try:
                spec = importlib.util.find_spec(name)  # e.g. an editable-install finder
            except (ImportError, ValueError):
                spec = None
        return spec
    pspec = _find_spec(parent)
    if pspec is None or pspec.submodule_search_locations is None:
        return None
    return importlib.machinery.PathFinder.find_spec(name, list(pspec.submodule_search_locations))


def _module_file(spec) -> Path | None:
    origin = getattr(spec, "origin", None)
    if not origin or origin in ("built-in", "frozen", "namespace") or not spec.has_location:
        return None
    p = Path(origin)
    return p if p.is_file() else None


def _imported_names(tree: ast.AST, name: str, is_package: bool) -> set[str]:
    """Every module name an import statement in ``tree`` may refer to."""
    package = name if is_package else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                out.add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                rel = "." * node.level + (node.module or "")
                try:
                    base = importlib.util.resolve_name(rel, package)
                except (ImportError, ValueError):
                    continue
            else:
                base = node.module or ""
            if not base:
                continue
            out.add(base)
            for alias in node.names:
                if alias.name != "*":
                    out.add(f"{base}.{alias.name}")
    return out


def _with_parents(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[: i + 1]) for i in range(len(parts))]


@lru_cache(maxsize=None)
def _module_entry(name: str) -> tuple[str, tuple[str, ...]] | None:
    """(sha256 of module ``name``'s file or ``"namespace"``, every module name its imports may
    refer to), or None when it cannot be found.  Read and parsed once per process: a table's
    plan hashes a dozen roots (steps, methods, protocols) whose closures share most modules."""
    spec = _find_spec(name)
    if spec is None:
        return None  # `from pkg import attr` where attr is not a submodule
    path = _module_file(spec)
    if path is None:
        return "namespace", ()
    digest = sha256_file(path)
    if path.suffix != ".py":
        return digest, ()
    is_pkg = spec.submodule_search_locations is not None
    key = f"{name}:{int(is_pkg)}:{digest}"
    known = _parsed_entries()
    entry = known.get(key)
    if not (isinstance(entry, list) and all(isinstance(i, str) for i in entry)):
        # not known yet, or a damaged entry (a miss: parsed again and written back right)
        try:
            tree = ast.parse(path.read_bytes(), filename=str(path))
        except SyntaxError:
            return digest, ()  # the bytes are hashed; importing it will fail loudly anyway
        global _parsed_dirty
        known[key], _parsed_dirty = sorted(_imported_names(tree, name, is_pkg)), True
    _parsed_used.add(key)
    return digest, tuple(known[key])


@lru_cache(maxsize=1)
def _reader_id() -> str:
    """The sha256 of this module's bytes: entries written by another version of the import
    reader (:func:`_imported_names`) are not used."""
    return sha256_file(Path(__file__))


def _parsed_entries() -> dict[str, list[str]]:
    """:data:`IMPORTS_CACHE`'s entries: empty when the file is missing, unreadable, of another
    schema or written by another version of this reader (each a miss, never an error)."""
    global _parsed
    if _parsed is None:
        from repro.paths import repro_home

        try:
            data = json.loads((repro_home() / IMPORTS_CACHE).read_text())
        except (OSError, ValueError):
            data = None
        ok = (isinstance(data, dict) and data.get("schema") == IMPORTS_CACHE_SCHEMA
              and data.get("reader") == _reader_id() and isinstance(data.get("entries"), dict))
        _parsed = dict(data["entries"]) if ok else {}
    return _parsed


def _save_parsed() -> None:
    """Write the entries parsed by this process into :data:`IMPORTS_CACHE` (atomically; a
    write that fails is skipped: the next process parses again)."""
    global _parsed_dirty
    if not _parsed_dirty or _parsed is None:
        return
    from repro.paths import repro_home

    keep = _parsed if len(_parsed) <= IMPORTS_CACHE_MAX else {
        k: v for k, v in _parsed.items() if k in _parsed_used}
    path = repro_home() / IMPORTS_CACHE
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps({"schema": IMPORTS_CACHE_SCHEMA, "reader": _reader_id(),
                                   "entries": keep}, sort_keys=True))
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
    _parsed_dirty = False


@lru_cache(maxsize=None)
def source_manifest(module_name: str) -> tuple[tuple[str, str], ...]:
    """Sorted ``(module name, sha256 of its file)`` pairs covered by :func:`source_hash`.

    Namespace packages (no file) appear with the digest ``"namespace"``.
    Raises :class:`~repro.errors.ConfigError` when ``module_name`` cannot be found.
    """
    if _find_spec(module_name) is None:
        raise ConfigError(f"cannot find module {module_name!r} (a job's implementation)")
    top = module_name.split(".")[0]
    scope = {ROOT_PACKAGE, top}

    def in_scope(n: str) -> bool:
        return n.split(".")[0] in scope

    seen: dict[str, str] = {}
    todo = _with_parents(module_name)
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        entry = _module_entry(name)
        if entry is None:
            continue
        seen[name], imports = entry
        for imp in imports:
            if in_scope(imp):
                todo.extend(n for n in _with_parents(imp) if n not in seen)
    _save_parsed()
    return tuple(sorted(seen.items()))


def joined_manifest(module_name: str, *more: str) -> dict[str, str]:
    """:func:`source_manifest` of ``module_name`` joined with those of ``more`` modules: the
    plug-ins a job loads by name at run time (a method's or a protocol's module, found through
    a registry, not an import statement)."""
    out = dict(source_manifest(module_name))
    for m in more:
        out.update(source_manifest(m))
    return out


@lru_cache(maxsize=None)
def source_hash(module_name: str, *more: str) -> str:
    """sha256 over :func:`joined_manifest` (see the module docstring)."""
    return content_key([list(p) for p in sorted(joined_manifest(module_name, *more).items())])


def clear_source_cache() -> None:
    """Forget cached hashes (tests; long-lived processes that reload code) and the entries of
    :data:`IMPORTS_CACHE` read so far (the next use reads the file again)."""
    global _parsed, _parsed_dirty
    _parsed, _parsed_dirty = None, False
    _parsed_used.clear()
    _module_entry.cache_clear()
    source_manifest.cache_clear()
    source_hash.cache_clear()
