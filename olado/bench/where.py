"""The record filter of ``olado profile --where`` (docs/benchmarking.md, "Subsets"): a small
expression language over record fields, parsed by hand and evaluated on a syntax tree -- never
by :func:`eval`.

    expr       := disjunct ("or" disjunct)*
    disjunct   := conjunct ("and" conjunct)*
    conjunct   := "not" conjunct | comparison
    comparison := value [("==" | "!=" | "<" | "<=" | ">" | ">=" | "in" | "not in") value]
    value      := NUMBER | STRING | FIELD | true | false | null | "(" expr ")" | "[" value ("," value)* "]"

A FIELD is a record key (letters, digits, ``_``, dotted for nested ones: ``machine.host``);
strings are quoted with ' or ". A lone value is true when it is truthy (``success``). A
comparison with a missing field, or between a number and a string, is false. Errors are
:class:`~olado.errors.ConfigError` naming ``--where``, the column and what was expected.

    N >= 216
    problem == 'zambezi12' and start != "sif"
    status in ['success', 'acceptable'] or not success
"""

from __future__ import annotations

import dataclasses
import operator
import re

from ..errors import ConfigError

_TOKEN = re.compile(r"""\s*(?:
    (?P<number>-?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)
  | (?P<string>'[^']*'|"[^"]*")
  | (?P<op>==|!=|<=|>=|<|>|\(|\)|\[|\]|,)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)
  )""", re.X)
_KEYWORDS = {"and", "or", "not", "in", "true", "false", "null"}
_COMPARE = {"==": operator.eq, "!=": operator.ne, "<": operator.lt, "<=": operator.le, ">": operator.gt,
            ">=": operator.ge}


def _error(text, column, what):
    return ConfigError(f"{what} at column {column + 1} of {text!r}", key="--where",
                       allowed="comparisons of fields with numbers or quoted strings, and/or/not, in [...]")


@dataclasses.dataclass(frozen=True)
class _Tok:
    kind: str       # number, string, op, name, keyword, end
    value: object
    column: int


def _tokens(text: str) -> list[_Tok]:
    out, pos = [], 0
    while pos < len(text):
        if text[pos:].strip() == "":
            break
        m = _TOKEN.match(text, pos)
        if not m or m.end() == pos:
            column = pos + len(text[pos:]) - len(text[pos:].lstrip())
            bad = text[column]
            what = "unterminated string" if bad in "'\"" else f"unexpected character {bad!r}"
            raise _error(text, column, what)
        kind = m.lastgroup
        raw = m.group(kind)
        column = m.start(kind)
        if kind == "number":
            value = float(raw) if any(c in raw for c in ".eE") else int(raw)
        elif kind == "string":
            value = raw[1:-1]
        else:
            value = raw
        if kind == "name" and raw in _KEYWORDS:
            kind = "keyword"
        out.append(_Tok(kind, value, column))
        pos = m.end()
    out.append(_Tok("end", None, len(text)))
    return out


class _Parser:
    def __init__(self, text):
        self.text, self.toks, self.i = text, _tokens(text), 0

    @property
    def tok(self) -> _Tok:
        return self.toks[self.i]

    def take(self, kind, value=None) -> bool:
        t = self.tok
        if t.kind == kind and (value is None or t.value == value):
            self.i += 1
            return True
        return False

    def fail(self, expected):
        t = self.tok
        found = "the end" if t.kind == "end" else repr(t.value)
        raise _error(self.text, t.column, f"expected {expected}, found {found}")

    def parse(self):
        if self.tok.kind == "end":
            raise _error(self.text, 0, "empty expression")
        tree = self.expr()
        if self.tok.kind != "end":
            self.fail("'and', 'or' or the end")
        return tree

    def expr(self):
        node = self.disjunct()
        while self.take("keyword", "or"):
            node = ("or", node, self.disjunct())
        return node

    def disjunct(self):
        node = self.conjunct()
        while self.take("keyword", "and"):
            node = ("and", node, self.conjunct())
        return node

    def conjunct(self):
        if self.take("keyword", "not"):
            return ("not", self.conjunct())
        return self.comparison()

    def comparison(self):
        left = self.value()
        t = self.tok
        if t.kind == "op" and t.value in _COMPARE:
            self.i += 1
            return ("cmp", t.value, left, self.value())
        if self.take("keyword", "in"):
            return ("in", left, self.value())
        if t.kind == "keyword" and t.value == "not" and self.toks[self.i + 1].value == "in":
            self.i += 2
            return ("not", ("in", left, self.value()))
        return ("truth", left)

    def value(self):
        t = self.tok
        if t.kind in ("number", "string"):
            self.i += 1
            return ("const", t.value)
        if t.kind == "name":
            self.i += 1
            return ("field", t.value)
        if t.kind == "keyword" and t.value in ("true", "false", "null"):
            self.i += 1
            return ("const", {"true": True, "false": False, "null": None}[t.value])
        if self.take("op", "("):
            node = self.expr()
            if not self.take("op", ")"):
                self.fail("')'")
            return node
        if self.take("op", "["):
            items = [self.value()]
            while self.take("op", ","):
                items.append(self.value())
            if not self.take("op", "]"):
                self.fail("',' or ']'")
            return ("list", items)
        self.fail("a field, a number, a quoted string, '(' or '['")


def _field(record, name):
    value = record
    for part in name.split("."):
        if not isinstance(value, dict) or part not in value:
            return _MISSING
        value = value[part]
    return value


_MISSING = object()


def _compare(op, a, b) -> bool:
    if a is _MISSING or b is _MISSING:
        return False
    numeric = (int, float)
    if isinstance(a, numeric) != isinstance(b, numeric) and a is not None and b is not None:
        return False
    if op not in ("==", "!=") and (a is None or b is None):
        return False
    return bool(_COMPARE[op](a, b))


class Where:
    """A parsed ``--where`` expression: ``Where(text)(record)`` -> bool; :meth:`fields` the field
    names it reads (checked against the records by :meth:`check_fields`)."""

    def __init__(self, text: str):
        if not isinstance(text, str):
            raise ConfigError(f"expected a string, got {type(text).__name__}", key="--where")
        self.text = text
        self.tree = _Parser(text).parse()

    def fields(self) -> set[str]:
        out = set()

        def walk(node):
            if node[0] == "field":
                out.add(node[1])
            for child in node[1:]:
                if isinstance(child, tuple):
                    walk(child)
                elif isinstance(child, list):
                    for c in child:
                        walk(c)
        walk(self.tree)
        return out

    def check_fields(self, records) -> None:
        """ConfigError for a field that no record has (a typo such as ``n >= 216``)."""
        for name in sorted(self.fields()):
            if records and all(_field(r, name) is _MISSING for r in records):
                known = sorted({k for r in records for k in r})
                raise ConfigError(f"no record has the field {name!r}", key="--where", allowed=", ".join(known))

    def _eval(self, node, record):
        kind = node[0]
        if kind == "const":
            return node[1]
        if kind == "field":
            return _field(record, node[1])
        if kind == "list":
            return [self._eval(n, record) for n in node[1]]
        if kind == "or":
            return self._truth(node[1], record) or self._truth(node[2], record)
        if kind == "and":
            return self._truth(node[1], record) and self._truth(node[2], record)
        if kind == "not":
            return not self._truth(node[1], record)
        if kind == "truth":
            return self._truth(node[1], record)
        if kind == "cmp":
            return _compare(node[1], self._eval(node[2], record), self._eval(node[3], record))
        if kind == "in":
            item, seq = self._eval(node[1], record), self._eval(node[2], record)
            if item is _MISSING or not isinstance(seq, (list, str)):
                return False
            if isinstance(seq, str):
                return isinstance(item, str) and item in seq
            return any(_compare("==", item, s) for s in seq)
        raise AssertionError(kind)  # pragma: no cover

    def _truth(self, node, record) -> bool:
        value = self._eval(node, record)
        return value is not _MISSING and bool(value)

    def __call__(self, record: dict) -> bool:
        return self._truth(self.tree, record)


def parse_where(text: str) -> Where:
    """Parse a ``--where`` expression (ConfigError naming the column of a mistake)."""
    return Where(text)
