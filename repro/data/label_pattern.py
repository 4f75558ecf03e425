"""The shape check of a data-set spec's ``[labels] pattern`` (issue 29), split from
:mod:`repro.data.dataset_spec` (which re-exports :func:`pattern_problem` and the caps).

A structural check over :mod:`re`'s own parse tree, not a second regex engine.  It refuses
the shapes whose matching backtracks exponentially and lets the rest through to the time
bound of :mod:`repro.data.dataset_labels` (``MATCH_SECONDS``):

- a repeat inside a repeat (``(a+)+``, ``(a?){30}``, ``(\\w+\\s?)*``) unless the outer repeat's
  body has a *required separator*: a single character or a small class that every pass of
  the outer repeat must match and that none of the inner repeats can match
  (``(?:[a-z]+-)*``, ``(?:_[a-z0-9]+)*``, ``\\w+(?: \\w+)*``): each pass then ends at a
  separator, and the text splits into passes one way only;
- an alternation inside a repeat (``(a|aa)*``) unless its branches start with characters no
  two of them share (``(?:walk|run)+``): one branch can start at a place;
- back-references and conditional groups; and caps on length, nesting and counts.
"""

from __future__ import annotations

import re

#: Label patterns: longest pattern, deepest nesting of groups, largest repetition count.
MAX_PATTERN_CHARS = 1000
MAX_PATTERN_DEPTH = 16
MAX_PATTERN_REPEAT = 1000
#: a class of at most this many characters may serve as a separator (it is enumerated)
_SEPARATOR_CHARS = 256

_NESTED = ("a repeat inside a repeat (such as (a+)+ or (a?){9}) can take exponential time; "
           "repeat a character class instead, or put a required separator (a character the "
           "inner repeat cannot match, such as _ or -) in the outer repeat")
_BRANCH = ("an alternation inside a repeat (such as (a|aa)*) can take exponential time; use "
           "a character class, or branches that start with different characters")


def pattern_problem(pattern: str) -> str | None:
    """Why the labels pattern is refused, or None (module docstring): not a regular
    expression, too long, nested too deep, a repetition count over the cap, a nested repeat
    or an alternation in a repeat of an unsafe shape, a back-reference."""
    import re._constants as C
    import re._parser as P

    if len(pattern) > MAX_PATTERN_CHARS:
        return f"the pattern is {len(pattern):,} characters, over the {MAX_PATTERN_CHARS} cap"
    try:
        tree = P.parse(pattern)
        re.compile(pattern)
    except re.error as e:
        return f"not a regular expression ({e})"
    except OverflowError:
        return f"a repetition count is over the {MAX_PATTERN_REPEAT} cap"
    except RecursionError:
        return f"groups nested deeper than {MAX_PATTERN_DEPTH} levels"
    repeats = (C.MAX_REPEAT, C.MIN_REPEAT, C.POSSESSIVE_REPEAT)
    icase = bool(tree.state.flags & re.IGNORECASE)
    stack = [(list(tree), 0)]
    outer = []  # the bodies of the repeats that may match more than once
    while stack:
        items, depth = stack.pop()
        if depth > MAX_PATTERN_DEPTH:
            return f"groups nested deeper than {MAX_PATTERN_DEPTH} levels"
        for op, av in items:
            if op in repeats:
                lo, hi, sub = av
                if lo > MAX_PATTERN_REPEAT or (hi != C.MAXREPEAT and hi > MAX_PATTERN_REPEAT):
                    return f"a repetition count is over the {MAX_PATTERN_REPEAT} cap"
                if hi == C.MAXREPEAT or hi > 1:
                    outer.append(list(sub))
                stack.append((list(sub), depth))
            elif op == C.SUBPATTERN:
                icase = icase or bool(av[1] & re.IGNORECASE)
                stack.append((list(av[-1]), depth + 1))
            elif op == C.ATOMIC_GROUP:
                stack.append((list(av), depth + 1))
            elif op in (C.ASSERT, C.ASSERT_NOT):
                stack.append((list(av[1]), depth + 1))
            elif op == C.BRANCH:
                stack.extend((list(b), depth + 1) for b in av[1])
            elif op in (C.GROUPREF, C.GROUPREF_EXISTS, C.GROUPREF_IGNORE, C.GROUPREF_LOC_IGNORE,
                        C.GROUPREF_UNI_IGNORE):
                return ("back-references and conditional groups are not supported in a "
                        "labels pattern")
    for body in outer:  # depth is capped now: the walks below stay shallow
        why = _repeat_problem(body, icase)
        if why is not None:
            return why
    return None


def _nodes(items):
    """Every (op, av) node in ``items``, at any depth."""
    import re._constants as C

    stack = list(items)
    while stack:
        op, av = stack.pop()
        yield op, av
        if op in (C.MAX_REPEAT, C.MIN_REPEAT, C.POSSESSIVE_REPEAT):
            stack.extend(av[2])
        elif op == C.SUBPATTERN:
            stack.extend(av[-1])
        elif op == C.ATOMIC_GROUP:
            stack.extend(av)
        elif op in (C.ASSERT, C.ASSERT_NOT):
            stack.extend(av[1])
        elif op == C.BRANCH:
            for b in av[1]:
                stack.extend(b)


def _repeat_problem(body: list, icase: bool) -> str | None:
    """Why the body of a repeat that may match more than once is unsafe, or None."""
    import re._constants as C

    repeats = (C.MAX_REPEAT, C.MIN_REPEAT, C.POSSESSIVE_REPEAT)
    inner_chars = []  # the character matchers inside the body's variable repeats
    for op, av in _nodes(body):
        if op in repeats and av[0] != av[1]:  # a fixed count ((?:_\d{2})+) is no choice
            inner_chars += [(o, a) for o, a in _nodes(av[2]) if o in _CHAR_OPS()]
            if any(o not in _CHAR_OPS() and o not in _NEUTRAL_OPS() for o, _ in _nodes(av[2])):
                inner_chars.append((C.ANY, None))  # anything else: it may match anything
        elif op == C.BRANCH and not _distinct_starts(av[1], icase):
            return _BRANCH
    if not inner_chars:
        return None
    for sep in _required_chars(body):
        chars = _enumerate(sep)
        if chars is None:
            continue
        variants = {v for c in chars for v in ((c, c.lower(), c.upper()) if icase else (c,))}
        if not any(_matches(m, c) for m in inner_chars for c in variants):
            return None
    return _NESTED


def _CHAR_OPS():
    import re._constants as C

    return (C.LITERAL, C.NOT_LITERAL, C.ANY, C.IN, C.CATEGORY)


def _NEUTRAL_OPS():
    """Nodes that match no character themselves (their children are walked)."""
    import re._constants as C

    return (C.MAX_REPEAT, C.MIN_REPEAT, C.POSSESSIVE_REPEAT, C.SUBPATTERN, C.ATOMIC_GROUP,
            C.BRANCH, C.AT, C.ASSERT, C.ASSERT_NOT)


def _required_chars(body: list):
    """The single-character matchers every match of ``body`` passes: its own items and
    those of groups at its top level (not those inside a repeat, a branch or a look-around)."""
    import re._constants as C

    for op, av in body:
        if op in (C.LITERAL, C.IN):
            yield op, av
        elif op == C.SUBPATTERN:
            yield from _required_chars(list(av[-1]))
        elif op in (C.MAX_REPEAT, C.MIN_REPEAT, C.POSSESSIVE_REPEAT) and av[0] >= 1:
            yield from _required_chars(list(av[2]))  # (?:_){2}: required too


def _enumerate(node) -> set[str] | None:
    """The characters a LITERAL or a small positive class matches, or None (too many, or a
    category or negated class: not enumerated)."""
    import re._constants as C

    op, av = node
    if op == C.LITERAL:
        return {chr(av)}
    out: set[str] = set()
    for o, a in av:
        if o == C.LITERAL:
            out.add(chr(a))
        elif o == C.RANGE and a[1] - a[0] < _SEPARATOR_CHARS:
            out.update(map(chr, range(a[0], a[1] + 1)))
        else:
            return None
        if len(out) > _SEPARATOR_CHARS:
            return None
    return out


_CATEGORY = {"CATEGORY_DIGIT": r"\d", "CATEGORY_NOT_DIGIT": r"\D", "CATEGORY_SPACE": r"\s",
             "CATEGORY_NOT_SPACE": r"\S", "CATEGORY_WORD": r"\w", "CATEGORY_NOT_WORD": r"\W"}


def _matches(node, ch: str) -> bool:
    """Whether the character matcher ``node`` may match ``ch`` (True when unsure)."""
    import re._constants as C

    op, av = node
    if op == C.LITERAL:
        return ch == chr(av)
    if op == C.NOT_LITERAL:
        return ch != chr(av)
    if op == C.CATEGORY:
        rx = _CATEGORY.get(str(av))
        return rx is None or re.fullmatch(rx, ch) is not None
    if op == C.IN:
        negate = any(o == C.NEGATE for o, _ in av)
        hit = False
        for o, a in av:
            if o == C.LITERAL:
                hit = hit or ch == chr(a)
            elif o == C.RANGE:
                hit = hit or a[0] <= ord(ch) <= a[1]
            elif o == C.CATEGORY:
                hit = hit or _matches((o, a), ch)
            elif o != C.NEGATE:
                return True
        return (not hit) if negate else hit
    return True


def _first(alt: list):
    """The first single-character matcher of a branch, or None (it may start empty, with an
    optional part, an anchor or a look-around)."""
    import re._constants as C

    for op, av in alt:
        if op in (C.LITERAL, C.IN):
            return op, av
        if op == C.SUBPATTERN:
            return _first(list(av[-1]))
        if op in (C.MAX_REPEAT, C.MIN_REPEAT, C.POSSESSIVE_REPEAT) and av[0] >= 1:
            return _first(list(av[2]))
        return None
    return None


def _distinct_starts(alts: list, icase: bool) -> bool:
    """Whether no two branches can start with the same character."""
    firsts = [_first(list(a)) for a in alts]
    if any(f is None for f in firsts):
        return False
    sets = []
    for f in firsts:
        chars = _enumerate(f)
        if chars is None:
            return False
        sets.append({v for c in chars for v in ((c, c.lower(), c.upper()) if icase else (c,))})
    seen: set[str] = set()
    for s in sets:
        if seen & s:
            return False
        seen |= s
    return True
