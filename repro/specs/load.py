"""Load and validate table specs from TOML, with errors that name file, row and field.

- :func:`load_spec` reads one file and returns a :class:`TableSpec`, or raises
  :class:`SpecValidationError` (a :class:`repro.errors.SpecError`) carrying every problem found.
- :func:`load_all` loads ``tables/<paper>/*.toml`` for the three papers under
  :func:`repro.paths.tables_root`.
- :func:`find_spec` resolves ``"marionette/table3"``, an unambiguous ``"table3"``-style alias,
  or a path, with a did-you-mean for anything else.
"""

from __future__ import annotations

import math
import re
import tomllib
import types
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from repro.errors import ConfigError, SpecError
from repro.paths import tables_root
from repro.specs import names
from repro.specs.schema import TableSpec, cross_check

_TOML_LINE = re.compile(r"\(at line (\d+), column (\d+)\)")


class SpecValidationError(SpecError):
    """Every problem of one spec file; ``problems`` holds one :class:`SpecError` each."""

    def __init__(self, problems: list[SpecError], file: str | Path | None = None, *,
                 check_command: str = "repro spec check"):
        self.problems = problems
        first = problems[0]
        more = f" (and {len(problems) - 1} more problem(s); run `{check_command}`)" \
            if len(problems) > 1 else ""
        super().__init__(first.problem + more, file, first.location)


#: Largest TOML file read (table specs, ``tables/scales.toml``, data-set specs), in bytes: the
#: largest shipped one, ``tables/scales.toml``, is 20 KB.  Read through
#: :func:`repro.data.sources.read_regular` (issue 29: ``repro spec check /dev/zero`` read
#: without end, and a FIFO blocked): a regular file only, at most cap + 1 bytes.
MAX_TOML_BYTES = 1024 ** 2


def read_toml(path: Path, cap: int | None = None, what: str = "the TOML file") -> dict[str, Any]:
    """Parse a TOML file of at most ``cap`` bytes (default :data:`MAX_TOML_BYTES`); a file
    that is not a regular file, is over the cap or has a syntax error becomes a
    :class:`SpecError` naming the file (and line)."""
    from repro.data.sources import read_regular

    data = read_regular(Path(path), MAX_TOML_BYTES if cap is None else cap, what, SpecError)
    try:
        parsed = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise SpecError(f"not UTF-8 text (byte {e.start})", path) from None
    except RecursionError:  # tomllib parses nested arrays/tables recursively
        raise SpecError(f"nested deeper than the parser can read (no spec nests more than "
                        f"{MAX_DEPTH} levels)", path) from None
    except tomllib.TOMLDecodeError as e:
        msg = str(e)
        m = _TOML_LINE.search(msg)
        if m:
            problem = _TOML_LINE.sub("", msg).strip()
            raise SpecError(f"line {m.group(1)}, column {m.group(2)}: TOML syntax error: {problem}",
                            path) from None
        raise SpecError(f"TOML syntax error: {msg}", path) from None
    if _depth(parsed) > MAX_DEPTH:
        raise SpecError(f"nested more than {MAX_DEPTH} levels deep (no spec needs that)", path)
    where = _non_finite(parsed)
    if where is not None:
        raise SpecError("nan and inf are not allowed (no spec value is one; the key recipe "
                        "cannot hash them)", path, where)
    return parsed


def _non_finite(value, at: str = "") -> str | None:
    """The dotted location of the first NaN or infinity in parsed TOML, or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return at or "(top level)"
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, list):
        items = ((f"[{i}]", v) for i, v in enumerate(value))
    else:
        return None
    for k, v in items:
        sub = f"{at}{k}" if str(k).startswith("[") else (f"{at}.{k}" if at else str(k))
        found = _non_finite(v, sub)
        if found is not None:
            return found
    return None


#: deepest nesting of tables and arrays a spec or scale file may have (real ones use about 5);
#: deeper input is refused before pydantic or the key recipe recurse into it
MAX_DEPTH = 32


def _depth(value, limit: int = MAX_DEPTH + 1) -> int:
    """Nesting depth of dicts and lists in ``value``, counted iteratively and up to ``limit``."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = list(v.values())
        if isinstance(v, list):
            d += 1
            deepest = max(deepest, d)
            if d <= limit:
                stack.extend((x, d) for x in v)
    return deepest


# -- turning pydantic errors into located, readable problems ------------------------------------


def _unwrap(tp):
    """The model class or container element type a location step leads into."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        for a in typing.get_args(tp):
            if isinstance(a, type) and issubclass(a, BaseModel):
                return a
        return tp
    if origin is typing.Annotated:
        return _unwrap(typing.get_args(tp)[0])
    return tp


def _model_at(root: type[BaseModel], loc: tuple) -> type[BaseModel] | None:
    cur: Any = root
    for step in loc:
        cur = _unwrap(cur)
        if isinstance(cur, type) and issubclass(cur, BaseModel) and isinstance(step, str):
            field = cur.model_fields.get(step)
            if field is None:
                field = next((f for f in cur.model_fields.values() if f.alias == step), None)
            if field is None:
                return None
            cur = field.annotation
            continue
        origin = typing.get_origin(cur)
        args = typing.get_args(cur)
        if origin is list and isinstance(step, int):
            cur = args[0]
        elif origin is dict and isinstance(step, str):
            cur = args[1]
        else:
            return None
    cur = _unwrap(cur)
    return cur if isinstance(cur, type) and issubclass(cur, BaseModel) else None


def _describe_loc(loc: tuple, data: Any) -> str:
    """``rows[3] (id 'a2m').reported.overall.acc`` from a pydantic location and the raw data."""
    parts: list[str] = []
    cur = data
    for step in loc:
        if isinstance(step, int):
            label = f"[{step}]"
            if isinstance(cur, list) and step < len(cur):
                cur = cur[step]
                if isinstance(cur, dict) and isinstance(cur.get("id"), str):
                    label += f" (id {cur['id']!r})"
            else:
                cur = None
            if parts:
                parts[-1] += label
            else:
                parts.append(label)
        else:
            parts.append(str(step))
            cur = cur.get(step) if isinstance(cur, dict) else None
    return ".".join(parts) if parts else "(top level)"


_UNION_TAGS = frozenset({"bool", "int", "float", "str"})


def _is_union_tag(step) -> bool:
    return isinstance(step, str) and (step in _UNION_TAGS or step.startswith(("list[", "dict[")))


def problems_from_validation(e: ValidationError, data: Any, model: type[BaseModel],
                              file: str | Path) -> list[SpecError]:
    """One :class:`SpecError` per problem pydantic found validating ``data`` (a parsed TOML
    file) as ``model``, each naming ``file`` and the field: what a table spec, the scale
    profiles and a data-set spec all report (:class:`SpecValidationError`)."""
    out: list[SpecError] = []
    seen: set[tuple] = set()
    for err in e.errors(include_url=False):
        loc = tuple(err["loc"])
        # a union reports one error per member, tagged by a member name in the location
        # ('bool', 'int', 'list[...]', 'dict[...]'); keep one error per location, reworded
        base = tuple(p for p in loc if not _is_union_tag(p))
        union = len(base) != len(loc)
        if base in seen:
            continue
        seen.add(base)
        typ, msg = err["type"], err["msg"]
        if union and typ.endswith("_type"):
            msg = "expected a string, number or boolean, or a list of them"
            if not isinstance(err.get("input"), (dict, list)):
                msg += f" (got {err['input']!r})"
            out.append(SpecError(msg, file, _describe_loc(base, data)))
            continue
        if typ == "extra_forbidden":
            parent = _model_at(model, base[:-1])
            fields = []
            if parent is not None:
                fields = [f.alias or n for n, f in parent.model_fields.items()]
            msg = f"unknown field {base[-1]!r}{names.suggest(str(base[-1]), fields)}"
            where = _describe_loc(base[:-1], data)
        elif typ == "missing":
            msg = f"missing required field {base[-1]!r}"
            where = _describe_loc(base[:-1], data)
        else:
            msg = re.sub(r"^(Value error|Assertion failed), ", "", msg)
            if "input" in err and typ not in ("value_error",) and not isinstance(err["input"], (dict, list)):
                msg += f" (got {err['input']!r})"
            where = _describe_loc(base, data)
        out.append(SpecError(msg, file, where))
    return out


# -- loading --------------------------------------------------------------------------------------


def _expected_id(path: Path) -> str | None:
    """``marionette/table3`` for ``.../marionette/table3.toml`` under a paper folder."""
    if path.parent.name in names.PAPERS:
        return f"{path.parent.name}/{path.stem}"
    return None


def validate_spec_data(data: dict[str, Any], file: str | Path) -> TableSpec:
    """Validate parsed TOML; raise :class:`SpecValidationError` with every problem."""
    try:
        spec = TableSpec.model_validate(data)
    except ValidationError as e:
        raise SpecValidationError(problems_from_validation(e, data, TableSpec, file), file) from None
    problems = [SpecError(p, file, loc) for loc, p in cross_check(spec)]
    expected = _expected_id(Path(file))
    if expected is not None and spec.id != expected:
        problems.insert(0, SpecError(f"spec id {spec.id!r} does not match its path "
                                     f"(expected {expected!r})", file, "id"))
    if not problems:
        from repro.specs.reported import reported_problems

        problems = [SpecError(p, file, loc) for loc, p in reported_problems(spec)]
    if problems:
        raise SpecValidationError(problems, file)
    return spec


def load_spec(path: str | Path) -> TableSpec:
    """Load and validate one spec file."""
    path = Path(path)
    data = read_toml(path)
    return validate_spec_data(data, display_path(path))


def display_path(path: Path) -> str:
    """The path relative to the tables root's parent (``tables/marionette/table3.toml``) when
    possible, else as given."""
    try:
        return str(path.resolve().relative_to(tables_root().resolve().parent))
    except ValueError:
        return str(path)


def spec_paths(root: str | Path | None = None) -> list[Path]:
    """``<root>/<paper>/*.toml`` for the three papers, sorted."""
    root = Path(root) if root is not None else tables_root()
    out: list[Path] = []
    for paper in names.PAPERS:
        folder = root / paper
        if folder.is_dir():
            out.extend(sorted(folder.glob("*.toml"), key=_natural_key))
    return out


def _natural_key(path: Path) -> list:
    """``table2`` before ``table10``, ``fig8`` before ``fig10``."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.stem)]


def load_all(root: str | Path | None = None) -> dict[str, TableSpec]:
    """Every spec under ``root`` (default :func:`repro.paths.tables_root`), keyed by id.
    The first invalid file raises; ``repro spec check`` reports them all."""
    specs: dict[str, TableSpec] = {}
    for p in spec_paths(root):
        spec = load_spec(p)
        if spec.id in specs:
            raise SpecError(f"duplicate spec id {spec.id!r}", display_path(p), "id")
        specs[spec.id] = spec
    return specs


def _aliases(ids: list[str]) -> dict[str, list[str]]:
    """Lower-cased short names → spec ids: ``table3`` → every ``*/table3``;
    ``marionette/table3``, ``marionette-table3``, ``marionette_table3`` → ``marionette/table3``."""
    out: dict[str, list[str]] = {}
    for sid in ids:
        paper, name = sid.split("/", 1)
        for alias in (sid, name, f"{paper}-{name}", f"{paper}_{name}", f"{paper}:{name}"):
            out.setdefault(alias.lower(), []).append(sid)
    return out


def find_spec(name: str, root: str | Path | None = None) -> TableSpec:
    """Resolve a spec by id, alias (case-insensitive) or path; unknown names get a
    did-you-mean, ambiguous ones the list of candidates (both :class:`ConfigError`)."""
    p = Path(name)
    if p.suffix == ".toml" and p.is_file():
        return load_spec(p)
    root_path = Path(root) if root is not None else tables_root()
    ids = [f"{q.parent.name}/{q.stem}" for q in spec_paths(root_path)]
    key = name.strip().removesuffix(".toml")
    if key.startswith("tables/"):
        key = key[len("tables/"):]
    matches = sorted(set(_aliases(ids).get(key.lower(), [])))
    if len(matches) == 1:
        return load_spec(root_path / f"{matches[0]}.toml")
    if len(matches) > 1:
        raise ConfigError(f"table {name!r} is ambiguous: {', '.join(matches)}")
    hint = names.suggest(key, ids + [i.split("/", 1)[1] for i in ids])
    raise ConfigError(f"unknown table {name!r}{hint}; `repro spec check` lists them")
