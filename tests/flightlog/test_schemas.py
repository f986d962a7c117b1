"""The JSON channels and the shipped layout as Foxglove reads them, by Foxglove's own rules ported here: every JSON
Schema the writer emits through the rules of Foxglove's JSON-schema parser (``parseJsonSchema`` of
``@foxglove/mcap-support``, the same rules in Lichtblick), every message path of
``configs/foxglove/flight_layout.json`` through its message-path grammar (``grammar.ne`` of the message-path syntax)
and resolved, as Foxglove resolves it (``messagePathStructures``, ``traverseStructure``), against the schema of its
topic in a real flight log (:func:`tests.flightlog.damage.flight_log`, a simulated hover through ``fly``); and every
JSON message of that log strict JSON that its schema describes.

Where Foxglove and Lichtblick differ, the stricter rule is taken: field names without ``-`` (Lichtblick allows it),
``integer`` read as ``float64`` (Foxglove reads ``uint32``, which more panels accept), filters with ``==`` only.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

import numpy as np
import pytest
from mcap.reader import make_reader

from groundstation.flightlog.mcap_log import encode_json
from groundstation.flightlog.schemas import SCHEMAS, schema_of
from tests.flightlog.damage import flight_log
from tests.peers import ROOT

LAYOUT = ROOT / "configs/foxglove/flight_layout.json"
ROS_PRIMITIVES = {"bool", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32",
                  "float64", "string", "time", "duration", "json"}
VALID_TYPES = {
    "Plot": {"bool", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64",
             "time", "duration", "string", "json"},  # plotableRosTypes
    "StateTransitions": {"bool", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "string",
                         "json"},  # transitionableRosTypes: no floats
}
"""What a path of each panel may end in (Foxglove's lists for the panels)."""


# -- Foxglove's JSON-schema parser ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Field:
    name: str
    type: str
    """A primitive's name, or the nested type's name."""
    is_array: bool = False


class Refused(Exception):
    """What Foxglove's parser throws: the channel shows no message at all."""


_PRIMITIVE = {"boolean": "bool", "number": "float64", "integer": "float64"}


def parse_json_schema(schema: dict, type_name: str) -> dict[str, list[Field]]:
    """The datatypes Foxglove makes of a channel's JSON Schema (type name -> fields), or :class:`Refused` with its
    message. Only ``type`` and ``properties``/``items`` count; ``required``, ``minItems`` and the rest are ignored,
    and a ``type`` that is not one of the strings below (a list: ``["number", "null"]``) is refused."""
    datatypes: dict[str, list[Field]] = {}

    def add(s: dict, name: str, key_path: list[str]) -> None:
        if s.get("type") != "object":
            raise Refused(f'Expected "type": "object" for schema {name}, got {json.dumps(s.get("type"))}')
        if not isinstance(s.get("properties"), dict):  # Object.entries(undefined) throws
            raise Refused(f"Cannot convert undefined or null to object (schema {name} has no properties)")
        fields = []
        for field_name, fs in s["properties"].items():
            where = ".".join([*key_path, field_name])
            if "oneOf" in fs:  # Foxglove takes numeric-constant enums only, Lichtblick none
                raise Refused(f"Unsupported type for {where}: oneOf")
            kind = fs.get("type")
            if kind == "string":
                if fs.get("contentEncoding") not in (None, "base64"):
                    raise Refused(f"Unsupported contentEncoding {json.dumps(fs['contentEncoding'])} in {where}")
                fields.append(Field(field_name, "string" if "contentEncoding" not in fs else "uint8",
                                    "contentEncoding" in fs))
            elif isinstance(kind, str) and kind in _PRIMITIVE:
                fields.append(Field(field_name, _PRIMITIVE[kind]))
            elif kind == "object":
                add(fs, f"{name}.{field_name}", [*key_path, field_name])
                fields.append(Field(field_name, f"{name}.{field_name}"))
            elif kind == "array":
                item = fs.get("items") or {}
                item_kind = item.get("type")
                if item_kind == "string" and "contentEncoding" not in item:
                    fields.append(Field(field_name, "string", True))
                elif isinstance(item_kind, str) and item_kind in _PRIMITIVE:
                    fields.append(Field(field_name, _PRIMITIVE[item_kind], True))
                elif item_kind == "object":
                    add(item, f"{name}.{field_name}", [*key_path, field_name])
                    fields.append(Field(field_name, f"{name}.{field_name}", True))
                else:
                    raise Refused(f"Unsupported type {json.dumps(item_kind)} for array item {where}")
            else:
                raise Refused(f"Unsupported type {json.dumps(kind)} for {where}")
        datatypes[name] = fields

    add(schema, type_name, [])
    return datatypes


# -- the message-path grammar --------------------------------------------------------------------------------------
_ID = r"[A-Za-z0-9_]+"
_INT = r"-?[0-9]+"
_VAR = rf"\$(?:{_ID})?"
_SLICE_VAL = rf"(?:{_INT}|{_VAR})"
_TOPIC = re.compile(rf"(?:/(?:{_ID})?)+|{_ID}(?:/(?:{_ID})?)*")
_NAME = re.compile(rf"\.({_ID})")
_SLICE = re.compile(rf"\[(?:(?P<index>{_SLICE_VAL})|(?P<start>{_SLICE_VAL})?:(?P<end>{_SLICE_VAL})?)\]")
_VALUE = rf"(?:{_INT}|'[^']*'|\"[^\"]*\"|true|false|{_VAR})"
_FILTER = re.compile(rf"\{{(?P<path>{_ID}(?:\.{_ID})*)?(?:==(?P<value>{_VALUE}))?\}}")
_MODIFIER = re.compile(rf"\.@(?:{_ID})?")
_JS_FLOAT = re.compile(r"\s*[+-]?(?:Infinity|(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)")


def parse_message_path(path: str) -> tuple[str, list[tuple]] | None:
    """(topic, parts) of a message path by the grammar, or None where it does not parse: ``topic`` then elements
    ``.name`` with at most one slice (``[0]``, ``[1:3]``, ``[:]``) and a filter (``{id==3}``) each, or a bare
    filter; an optional trailing ``.`` (an unfinished path: an empty name, which resolves to nothing) and an
    optional modifier ``.@name``. Parts: ``("name", str)``, ``("slice", str)``, ``("filter", [names], value)``."""
    m = _TOPIC.match(path)
    if m is None:
        return None
    topic, i, parts = m.group(), m.end(), []
    while True:  # a filter after a name's slice reads the same as a filter element of its own
        if f := _FILTER.match(path, i):
            parts.append(("filter", f["path"].split(".") if f["path"] else [], f["value"]))
            i = f.end()
        elif n := _NAME.match(path, i):
            parts.append(("name", n[1]))
            i = n.end()
            if s := _SLICE.match(path, i):
                parts.append(("slice", s.group()))
                i = s.end()
        else:
            break
    if path[i:] == ".":
        parts.append(("name", ""))
        i += 1
    elif mod := _MODIFIER.match(path, i):
        i = mod.end()
    return (topic, parts) if i == len(path) else None


def structure(datatypes: dict[str, list[Field]], name: str, seen: tuple[str, ...] = ()) -> dict:
    """Foxglove's navigable structure of a datatype: ``{"message": {field: item}}``, ``{"array": item}`` or
    ``{"primitive": type}`` (a field of a type already being expanded is left out, as Foxglove does)."""
    fields = {}
    for f in datatypes[name]:
        if f.type in seen:
            continue
        item = {"primitive": f.type} if f.type in ROS_PRIMITIVES else structure(datatypes, f.type, (*seen, f.type))
        fields[f.name] = {"array": item} if f.is_array else item
    return {"message": fields}


def resolve(item: dict | None, parts: list[tuple]) -> dict | None:
    """The structure item a path's parts lead to (``traverseStructure``), None where it is invalid."""
    for part in parts:
        if item is None:
            return None
        if part[0] == "name":
            item = item["message"].get(part[1]) if "message" in item else None
        elif part[0] == "slice":
            item = item.get("array")
        else:  # a filter stays on the message it filters, and names a field of it
            if "message" not in item or not part[1] or part[2] is None:
                return None
            inner = item
            for name in part[1]:
                inner = inner["message"].get(name) if inner and "message" in inner else None
            if inner is None:
                return None
    return item


def is_reference_line(value: str) -> bool:
    """A Plot series whose value starts like a number (JavaScript's parseFloat) is a horizontal line, no path."""
    return _JS_FLOAT.match(value) is not None


# -- the real log ---------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def log_channels() -> dict[str, tuple]:
    """topic -> (message encoding, schema encoding, schema name, schema) of the real flight log."""
    with open(flight_log(), "rb") as fh:
        summary = make_reader(fh).get_summary()
    return {c.topic: (c.message_encoding, summary.schemas[c.schema_id].encoding, summary.schemas[c.schema_id].name,
                      summary.schemas[c.schema_id].data) for c in summary.channels.values()}


def _strict_json(data: bytes):
    def refuse(constant):
        raise ValueError(f"{constant} is not JSON")
    return json.loads(data, parse_constant=refuse)


def violations(value, schema: dict, where: str = "") -> list[str]:
    """Where ``value`` breaks ``schema`` (type, required, properties with nothing undeclared, items, minItems,
    maxItems: what the flight log's schemas use)."""
    kind = schema["type"]
    number = isinstance(value, int | float) and not isinstance(value, bool)
    ok = {"object": isinstance(value, dict), "array": isinstance(value, list), "string": isinstance(value, str),
          "boolean": isinstance(value, bool), "number": number,
          "integer": number and float(value).is_integer()}.get(kind, False)
    if not ok:
        return [f"{where or '/'}: {value!r} is not {kind!r}"]
    out = []
    if kind == "object":
        props = schema.get("properties", {})
        out += [f"{where}.{k}: required, absent" for k in schema.get("required", ()) if k not in value]
        for k, v in value.items():
            out += violations(v, props[k], f"{where}.{k}") if k in props else [f"{where}.{k}: not in the schema"]
    elif kind == "array":
        if not schema.get("minItems", 0) <= len(value) <= schema.get("maxItems", len(value)):
            out.append(f"{where}: {len(value)} items")
        for i, v in enumerate(value):
            out += violations(v, schema["items"], f"{where}[{i}]")
    return out


# -- (a) the schemas ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("topic", [*SCHEMAS, "/unknown"])
def test_every_schema_the_writer_emits_is_one_foxglove_reads(topic):
    schema = json.loads(schema_of(topic))
    datatypes = parse_json_schema(schema, topic.strip("/").replace("/", "."))
    assert datatypes and all(fields for name, fields in datatypes.items() if name != "unknown"), datatypes


def test_the_logs_json_channels_carry_schemas_foxglove_reads(log_channels):
    json_channels = {t: c for t, c in log_channels.items() if c[0] == "json"}
    assert set(SCHEMAS) <= set(json_channels)  # a hover writes all six
    for topic, (_, schema_encoding, name, data) in json_channels.items():
        assert schema_encoding == "jsonschema", topic
        parse_json_schema(json.loads(data), name)


def test_every_json_message_is_strict_json_its_schema_describes(log_channels):
    """No NaN or Infinity anywhere (the first /mocap/stats has no rate yet: the member is absent), every member
    declared (so Foxglove offers it), every type as declared."""
    schemas = {t: json.loads(c[3]) for t, c in log_channels.items() if c[0] == "json"}
    seen = dict.fromkeys(schemas, 0)
    with open(flight_log(), "rb") as fh:
        for _, ch, m in make_reader(fh).iter_messages(topics=list(schemas)):
            record = _strict_json(m.data)
            assert violations(record, schemas[ch.topic]) == [], (ch.topic, record)
            if ch.topic == "/mocap/stats" and not seen[ch.topic]:
                assert "rate_hz" not in record  # the first: no interval to measure a rate over yet
            seen[ch.topic] += 1
    assert all(seen.values()), seen


def test_the_writer_leaves_out_what_is_not_finite():
    d = {"t_s": 1.0, "rate_hz": math.nan, "mocap_age_s": math.inf, "v": np.array([1.0, np.nan, 2.0]),
         "w": [1.0, 2.0], "modules": [{"link_latency_s": np.float64(np.nan), "battery_v": np.float32(4.0)},
                                      {"link_latency_s": 0.004}], "n": np.int64(3)}
    assert _strict_json(encode_json(d)) == {"t_s": 1.0, "w": [1.0, 2.0], "modules": [{"battery_v": 4.0},
                                                                                       {"link_latency_s": 0.004}],
                                            "n": 3}


# -- (b) the layout -------------------------------------------------------------------------------------------------
def _layout_paths() -> list[tuple[str, str]]:
    """(panel kind, message path) of every series of every Plot and State Transitions panel."""
    panels = json.loads(LAYOUT.read_text())["configById"]
    return [(key.split("!")[0], p["value"]) for key, panel in panels.items() if key.split("!")[0] in VALID_TYPES
            for p in panel["paths"] if not is_reference_line(p["value"])]


def test_the_grammar_as_ported():
    assert parse_message_path("/control.modules[0].command_frac_umax[2]") == (
        "/control", [("name", "modules"), ("slice", "[0]"), ("name", "command_frac_umax"), ("slice", "[2]")])
    assert parse_message_path("/a/b.c[:]{id==3}.d.@derivative") == (
        "/a/b", [("name", "c"), ("slice", "[:]"), ("filter", ["id"], "3"), ("name", "d")])
    assert parse_message_path("/control.state.") == ("/control", [("name", "state"), ("name", "")])
    for bad in ("/control.motors[0][0]", "/control.a-b", "/control..a", "/control.a[x]", "/control.a[0"):
        assert parse_message_path(bad) is None, bad
    assert is_reference_line("1") and is_reference_line("-0.5e2") and not is_reference_line("/control.t_s")


def test_every_series_is_labelled_and_the_layout_has_its_panels():
    panels = json.loads(LAYOUT.read_text())["configById"]
    assert {k.split("!")[0] for k in panels} == {"3D", "Plot", "StateTransitions", "Log"}
    assert panels["3D!assembly"]["followTf"] == "body"
    series = [p for k, panel in panels.items() if k.split("!")[0] in VALID_TYPES for p in panel["paths"]]
    assert series and all(p.get("label") for p in series), [p["value"] for p in series if not p.get("label")]
    plotted = {p["value"] for p in series}
    assert {"/control.phase", "/control.position_error_m[0]", "/control.command_max_frac_umax",
            "/control.mocap_age_s", "/backend/telemetry.modules[0].link_latency_s"} <= plotted
    for key, panel in panels.items():  # a title that names angles names only what it plots
        if "roll and yaw" in panel.get("title", ""):
            assert not any("rpy_deg[1]" in p["value"] for p in panel["paths"]), key


@pytest.mark.parametrize("kind, path", _layout_paths(), ids=[p for _, p in _layout_paths()])
def test_every_layout_path_parses_and_resolves_in_a_real_log(kind, path, log_channels):
    parsed = parse_message_path(path)
    assert parsed is not None, f"{path}: not a message path in Foxglove's grammar"
    topic, parts = parsed
    assert topic in log_channels, f"{path}: the log has no channel {topic}"
    _, schema_encoding, name, data = log_channels[topic]
    assert schema_encoding == "jsonschema", path
    datatypes = parse_json_schema(json.loads(data), name)
    item = resolve(structure(datatypes, name), parts)
    assert item is not None, f"{path}: no such field in the schema of {topic} (as logged)"
    assert item.get("primitive") in VALID_TYPES[kind], f"{path}: ends in {item}, not a value a {kind} panel shows"


def test_the_3d_and_log_panels_read_channels_of_the_log(log_channels):
    panels = json.loads(LAYOUT.read_text())["configById"]
    assert set(panels["3D!assembly"]["topics"]) <= set(log_channels)
    assert panels["Log!events"]["topicToRender"] in log_channels
