"""A Sphinx directive, ``bench-config-schema``: the bench config's fields, generated.

The bench config is validated by the pydantic models in the package ``benchctl/config/``
(``BenchConfig`` and the models of its sections). This renders their JSON Schema
(``benchctl.config.config_schema()``, what ``benchctl schema config`` prints) as one table per
section — every field with its type, its default (or *required*), its bounds and its meaning —
so the reference cannot drift from the code.
Documentation only: nothing in the product is changed.
"""

from __future__ import annotations

import json
import re
from typing import Any

from docutils import nodes
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

_BOUNDS = (
    ("minimum", "≥ {}"),
    ("exclusiveMinimum", "> {}"),
    ("maximum", "≤ {}"),
    ("exclusiveMaximum", "< {}"),
    ("minLength", "length ≥ {}"),
    ("maxLength", "length ≤ {}"),
    ("minItems", "≥ {} items"),
    ("maxItems", "≤ {} items"),
    ("pattern", "matches ``{}``"),
)


def _lit(value: Any) -> str:
    text = json.dumps(value, ensure_ascii=False)
    return f"``{text}``" if "`" not in text else text


def _ref_name(ref: str) -> str:
    return ref.rsplit("/", 1)[-1]


def _type(spec: dict[str, Any]) -> str:
    if "$ref" in spec:
        return f"*{_ref_name(spec['$ref'])}* (below)"
    if "enum" in spec:
        return " | ".join(_lit(v) for v in spec["enum"])
    if "const" in spec:
        return _lit(spec["const"])
    for key in ("anyOf", "oneOf", "allOf"):
        if key in spec:
            return " or ".join(_type(s) for s in spec[key])
    kind = spec.get("type", "any")
    if kind == "array":
        items = spec.get("items")
        if isinstance(items, dict):
            return f"list of {_type(items)}"
        if "prefixItems" in spec:
            return "[" + ", ".join(_type(s) for s in spec["prefixItems"]) + "]"
        return "list"
    if kind == "object" and isinstance(spec.get("additionalProperties"), dict):
        return f"mapping of {_type(spec['additionalProperties'])}"
    return str(kind) if isinstance(kind, str) else " or ".join(kind)


def _bounds(spec: dict[str, Any]) -> str:
    found = [fmt.format(spec[key]) for key, fmt in _BOUNDS if key in spec]
    for key in ("anyOf", "oneOf"):
        for sub in spec.get(key, []):
            found += [fmt.format(sub[k]) for k, fmt in _BOUNDS if k in sub]
    if isinstance(spec.get("items"), dict):
        found += [fmt.format(spec["items"][k]) for k, fmt in _BOUNDS if k in spec["items"]]
    return ", ".join(found)


def _refs(spec: Any) -> list[str]:
    """The models a field refers to, in order."""
    out: list[str] = []
    if isinstance(spec, dict):
        if "$ref" in spec:
            out.append(_ref_name(spec["$ref"]))
        for value in spec.values():
            out += _refs(value)
    elif isinstance(spec, list):
        for value in spec:
            out += _refs(value)
    return out


def schema_tables() -> list[tuple[str, list[str], str, list[list[str]]]]:
    """(model, where it appears, what it is, rows of field / type / default / bounds / meaning)
    per model."""
    from benchctl.config import config_schema

    schema = config_schema()
    defs: dict[str, Any] = schema.get("$defs", {})
    models: dict[str, dict[str, Any]] = {"BenchConfig": schema, **defs}
    # each model with the places it appears at, in the order they are first met
    paths: dict[str, list[str]] = {"BenchConfig": ["(top level)"]}
    queue = ["BenchConfig"]
    while queue:
        name = queue.pop(0)
        for field, spec in models[name].get("properties", {}).items():
            for ref in _refs(spec):
                if ref not in models or "properties" not in models[ref]:
                    continue
                where = [
                    f"{p}.{field}" if p != "(top level)" else field for p in paths[name]
                ]
                if ref not in paths:
                    paths[ref] = []
                    queue.append(ref)
                paths[ref] += [w for w in where if w not in paths[ref]]
    tables: list[tuple[str, list[str], str, list[list[str]]]] = []
    for name, where in paths.items():
        model = models[name]
        required = set(model.get("required", []))
        rows = []
        for field, spec in model.get("properties", {}).items():
            if field in required:
                default = "*required*"
            elif "default" in spec:
                default = _lit(spec["default"])
            else:
                default = ""
            meaning = spec.get("description", "").replace("`", "``").replace("````", "``")
            rows.append([f"``{field}``", _type(spec), default, _bounds(spec), meaning])
        tables.append((name, where, model.get("description", ""), rows))
    return tables


def _inline(text: str) -> list[nodes.Node]:
    """Text with ``literal`` and *emphasis* spans, as docutils nodes (no markup parser)."""
    out: list[nodes.Node] = []
    for i, part in enumerate(re.split(r"``(.*?)``", text)):
        if i % 2:
            out.append(nodes.literal(part, part))
            continue
        for j, bit in enumerate(re.split(r"\*([^*]+)\*", part)):
            if bit:
                out.append(nodes.emphasis(bit, bit) if j % 2 else nodes.Text(bit))
    return out


def _table(rows: list[list[str]]) -> nodes.table:
    head = ["field", "type", "default", "bounds", "meaning"]
    table = nodes.table()
    group = nodes.tgroup(cols=len(head))
    table += group
    for width in (16, 18, 10, 12, 44):
        group += nodes.colspec(colwidth=width)
    thead, tbody = nodes.thead(), nodes.tbody()
    group += thead
    group += tbody
    for target, cells in ((thead, [head]), (tbody, rows)):
        for cells_of_row in cells:
            row = nodes.row()
            for cell in cells_of_row:
                entry = nodes.entry()
                entry += nodes.paragraph("", "", *_inline(cell))
                row += entry
            target += row
    return table


class BenchConfigSchema(SphinxDirective):
    """``bench-config-schema``: the tables of every bench config section's fields."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        out: list[nodes.Node] = []
        for name, where, about, rows in schema_tables():
            out.append(nodes.rubric(name, name))
            if about:
                first = about.split("\n\n")[0].replace("`", "``").replace("````", "``")
                out.append(nodes.paragraph("", "", *_inline(first)))
            at = ", ".join(f"``{w}``" if w != "(top level)" else w for w in where)
            out.append(nodes.paragraph("", "", *_inline(f"At: {at}")))
            out.append(_table(rows))
        return out


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("bench-config-schema", BenchConfigSchema)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
