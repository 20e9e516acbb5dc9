"""Proves a document valid against a JSON schema without importing jsonschema, when it can.

`fleet.py` checks every service's `compose:` keys against the vendored Compose schema. Importing
jsonschema (attrs, referencing, urllib, ssl) and building its validator took 60-100 ms of every
`validate`, `check` and `render`, a fifth of the 0.5 s target for 500 robots (issue 18), while
almost every fleet file's `compose:` keys are valid.

`verdict(schema, value)` answers True (valid), False (invalid) or None (this checker cannot
tell: a keyword or a case it does not implement). Only True is acted on: the caller skips
jsonschema then, and in every other case runs jsonschema, whose messages the user sees. So this
module never writes a message and never decides that something is invalid; a wrong True is the
only mistake it could make, and tests/unit/test_schema_quick.py holds it to jsonschema's answer.

It implements the part of draft 2019-09 the Compose schema uses: type, properties,
patternProperties, additionalProperties, items (one schema), required, enum (strings),
uniqueItems (strings), minimum, maximum, oneOf, anyOf and local $ref. `format` is an annotation
for jsonschema's validators unless a format checker is given (fleet.py gives none).
"""
from __future__ import annotations

import re
from typing import Any, Callable, Mapping, Optional

Verdict = Optional[bool]   # True valid, False invalid, None unknown
_ANNOTATIONS = frozenset({"$schema", "id", "$id", "title", "description", "deprecated", "format", "default",
                          "$comment", "examples", "definitions", "$defs"})
# Read together (_object): additionalProperties applies to the keys the other two do not match.
_OBJECT = ("properties", "patternProperties", "additionalProperties")
_TYPES: dict[str, Callable[[Any], bool]] = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    "integer": lambda v: (isinstance(v, int) and not isinstance(v, bool)) or (isinstance(v, float) and v.is_integer()),
}


def verdict(schema: Any, value: Any, root: Mapping[str, Any] | None = None) -> Verdict:
    """Is `value` valid against `schema` (whose local $refs point into `root`, default `schema`)?"""
    return _check(schema, value, schema if root is None else root)


def _check(schema: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
    if isinstance(schema, bool):
        return schema
    if not isinstance(schema, dict):
        return None
    results = []
    for key, rule in schema.items():
        if key in _ANNOTATIONS or key in _OBJECT:
            continue
        check = _KEYWORDS.get(key)
        if check is None:
            return None
        results.append(check(rule, value, root))
    if any(key in schema for key in _OBJECT):
        results.append(_object(schema, value, root))
    return _all(results)


def _all(results: list[Verdict]) -> Verdict:
    if False in results:
        return False
    return None if None in results else True


def _type(rule: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
    names = rule if isinstance(rule, list) else [rule]
    if any(name not in _TYPES for name in names):
        return None
    return any(_TYPES[name](value) for name in names)


def _object(schema: Mapping[str, Any], value: Any, root: Mapping[str, Any]) -> Verdict:
    """properties, patternProperties and additionalProperties together (the last depends on the other two)."""
    if not isinstance(value, dict):
        return True
    properties = schema.get("properties", {})
    patterns = schema.get("patternProperties", {})
    extra = schema.get("additionalProperties", True)
    results: list[Verdict] = []
    for key, item in value.items():
        if not isinstance(key, str):
            return None
        matched = False
        if key in properties:
            matched = True
            results.append(_check(properties[key], item, root))
        for pattern, sub in patterns.items():
            if re.search(pattern, key):
                matched = True
                results.append(_check(sub, item, root))
        if not matched:
            results.append(_check(extra, item, root))
    return _all(results)


def _items(rule: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
    if not isinstance(value, list):
        return True
    if not isinstance(rule, (dict, bool)):
        return None   # the list (tuple) form
    return _all([_check(rule, item, root) for item in value])


def _unique(rule: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
    if rule is not True or not isinstance(value, list):
        return True
    if not all(isinstance(item, str) for item in value):
        return None   # jsonschema's equality (1 == 1.0, true vs 1) is not worth copying
    return len(set(value)) == len(value)


def _required(rule: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
    return not isinstance(value, dict) or all(key in value for key in rule)


def _enum(rule: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
    if not isinstance(value, str):
        return None
    return value in [choice for choice in rule if isinstance(choice, str)]


def _bound(compare: Callable[[Any, Any], bool]) -> Callable[[Any, Any, Mapping[str, Any]], Verdict]:
    def check(rule: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return True
        return compare(value, rule)
    return check


def _one_of(rule: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
    results = [_check(sub, value, root) for sub in rule]
    return None if None in results else results.count(True) == 1


def _any_of(rule: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
    results = [_check(sub, value, root) for sub in rule]
    if True in results:
        return True
    return None if None in results else False


def _ref(rule: Any, value: Any, root: Mapping[str, Any]) -> Verdict:
    if not isinstance(rule, str) or not rule.startswith("#/"):
        return None
    target: Any = root
    for part in rule[2:].split("/"):
        if not isinstance(target, dict) or part not in target:
            return None
        target = target[part]
    return _check(target, value, root)


_KEYWORDS: dict[str, Callable[[Any, Any, Mapping[str, Any]], Verdict]] = {
    "type": _type, "items": _items, "uniqueItems": _unique, "required": _required, "enum": _enum,
    "minimum": _bound(lambda v, low: v >= low), "maximum": _bound(lambda v, high: v <= high),
    "oneOf": _one_of, "anyOf": _any_of, "$ref": _ref,
}
