"""schema_quick.verdict against jsonschema itself, over the vendored Compose schema.

A True from schema_quick makes fleet.py skip jsonschema, so True must never be said of a value
jsonschema refuses. False is never acted on, but must agree too (a checker that disagrees on
False has a bug that could as well be on True).
"""
from __future__ import annotations

import json
import random
from typing import Any

import jsonschema
import pytest

from rosdeploy import fleet, schema_quick

SCHEMA = json.loads(fleet.COMPOSE_SCHEMA.read_text(encoding="utf-8"))
VALIDATOR = jsonschema.Draft201909Validator(SCHEMA)
KEYS = sorted(k for k in SCHEMA["definitions"]["service"]["properties"] if k not in fleet.MANAGED_COMPOSE)

SCALARS: list[Any] = ["x", "", "SYS_NICE", "80:80", "1g", "x-y", 0, 1, -1, 2.5, 1.0, True, False, None]


def _random_value(rng: random.Random, depth: int = 0) -> Any:
    kind = rng.randrange(3 if depth < 3 else 1)
    if kind == 0:
        return rng.choice(SCALARS)
    if kind == 1:
        return [_random_value(rng, depth + 1) for _ in range(rng.randrange(4))]
    keys = ["soft", "hard", "target", "published", "source", "type", "x-a", "name", "driver", "options", "a"]
    return {rng.choice(keys): _random_value(rng, depth + 1) for _ in range(rng.randrange(4))}


def _from_schema(rng: random.Random, schema: Any, depth: int = 0) -> Any:
    """A value shaped like `schema` (often valid), with random slips (often not)."""
    if rng.random() < 0.1 or depth > 6 or not isinstance(schema, dict):
        return _random_value(rng, depth)
    if "$ref" in schema:
        target: Any = SCHEMA
        for part in schema["$ref"][2:].split("/"):
            target = target[part]
        return _from_schema(rng, target, depth + 1)
    for key in ("oneOf", "anyOf"):
        if key in schema:
            return _from_schema(rng, rng.choice(schema[key]), depth + 1)
    kind = schema.get("type")
    kind = rng.choice(kind) if isinstance(kind, list) else kind
    if "enum" in schema:
        return rng.choice(schema["enum"])
    if kind == "object":
        names = list(schema.get("properties", {})) + ["x-extra", "unknown"]
        return {name: _from_schema(rng, schema.get("properties", {}).get(name, {}), depth + 1)
                for name in rng.sample(names, min(len(names), rng.randrange(1, 4)))}
    if kind == "array":
        items = [_from_schema(rng, schema.get("items", {}), depth + 1) for _ in range(rng.randrange(4))]
        return items + items[:1] if rng.random() < 0.1 else items   # a duplicate, for uniqueItems
    samples = {"string": ["a", "SYS_NICE", "80:80", ""], "integer": [0, 5, 1.0, -3], "number": [0.5, 2, -1],
               "boolean": [True, False], "null": [None]}
    return rng.choice(samples.get(kind, SCALARS))


def _agrees(extra: dict[str, Any]) -> str | None:
    """None when schema_quick's verdict is consistent with jsonschema's errors, else what differs."""
    document = {"services": {"s": extra}}
    quick = schema_quick.verdict(SCHEMA, document)
    errors = list(VALIDATOR.iter_errors(document))
    if quick is True and errors:
        return f"quick says valid, jsonschema: {errors[0].message}"
    if quick is False and not errors:
        return "quick says invalid, jsonschema says valid"
    return None


@pytest.mark.parametrize("key", KEYS)
def test_every_key_agrees_with_jsonschema(key: str) -> None:
    rng = random.Random(key)
    schema = SCHEMA["definitions"]["service"]["properties"][key]
    values = [*SCALARS, [], ["a"], ["a", "a"], [1], {}, {"a": "b"}, {"a": 1}, {"x-y": 1}]
    values += [_from_schema(rng, schema) for _ in range(150)]
    wrong = [(v, why) for v in values if (why := _agrees({key: v}))]
    assert not wrong, wrong[:3]


def test_it_vouches_for_common_compose_keys() -> None:
    """The point of the module: typical `compose:` blocks need no jsonschema."""
    for extra in ({"cap_add": ["SYS_NICE"]}, {"ulimits": {"rtprio": 99, "memlock": {"soft": -1, "hard": -1}}},
                  {"ipc": "host", "pid": "host"}, {"sysctls": {"net.core.rmem_max": 2147483647}},
                  {"extra_hosts": ["fleet.local:10.0.0.1"], "x-note": {"any": ["thing"]}},
                  {"ports": ["7400:7400/udp", "8080:80"]}, {"stop_grace_period": "20s"}):
        assert schema_quick.verdict(SCHEMA, {"services": {"s": extra}}) is True, extra


def test_it_never_vouches_for_what_jsonschema_refuses() -> None:
    for extra in ({"cap_add": "SYS_NICE"}, {"cap_add": ["A", "A"]}, {"ulimits": {"nofile": {"soft": 1}}},
                  {"cpu_count": -1}, {"oom_score_adj": 5000}, {"init": "yes"}, {"x-a": 1, "tmpfs": 5}):
        assert schema_quick.verdict(SCHEMA, {"services": {"s": extra}}) is not True, extra
        assert list(VALIDATOR.iter_errors({"services": {"s": extra}})), extra


def test_unknown_keywords_and_remote_refs_are_not_guessed() -> None:
    assert schema_quick.verdict({"multipleOf": 2}, 3) is None
    assert schema_quick.verdict({"$ref": "https://example.com/s.json"}, 3) is None
    assert schema_quick.verdict({"type": "string", "minLength": 3}, "ab") is None
    assert schema_quick.verdict({"type": "integer"}, True) is False   # a bool is not a number in JSON schema


def test_fleet_file_compose_check_still_reports_jsonschema_messages(tmp_path: Any) -> None:
    """The fast path changes nothing a user sees: an invalid value still gets jsonschema's message."""
    r = fleet.Reader(fleet.Doc(str(tmp_path / "fleet.yml"), {}))
    fleet._compose_schema(r, ("services", "s", "compose"), {"cap_add": "SYS_NICE", "cpu_count": -1})
    messages = sorted(p.message for p in r.problems)
    assert len(messages) == 2 and all(m.startswith("not valid for compose: ") for m in messages), messages
    assert any("'SYS_NICE' is not of type 'array'" in m for m in messages), messages
