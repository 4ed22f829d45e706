"""The one YAML reader: every YAML file benchctl reads goes through :func:`read_yaml`.

Bench configs, profiles, plans, register maps and the panel's settings are read by
``BenchYamlLoader``: PyYAML's safe loader plus these rules (docs/reference/config.md, "YAML
rules"):

- the file is UTF-8 (else an error naming the byte offset and line);
- a key given twice in one mapping is an error (PyYAML silently keeps the last);
- nesting deeper than ``MAX_YAML_DEPTH`` is an error (PyYAML recurses: RecursionError);
- a document whose aliases expand to more than ``MAX_YAML_NODES`` nodes is an error (an
  "alias bomb" costs exponential time and memory downstream), so is a recursive alias;
- YAML 1.1 sexagesimal numbers (``30:00`` → 1800) and leading-zero octals (``010`` → 8) are
  not numbers: they stay strings, and a numeric field refuses them (or, for ``010``, reads
  the decimal 10);
- any other failure of PyYAML's constructors (a bad date, ``0x_``) is a ``ConfigError``.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from benchctl.errors import ConfigError
from benchctl.textfile import MAX_YAML_BYTES, decode_utf8, read_input
from benchctl.validation import shown_value

MAX_YAML_DEPTH = 100
MAX_YAML_NODES = 100_000

_INT_TAG = "tag:yaml.org,2002:int"
_FLOAT_TAG = "tag:yaml.org,2002:float"
_MERGE_TAG = "tag:yaml.org,2002:merge"
# PyYAML's YAML 1.1 patterns without the sexagesimal and the leading-zero octal forms
_INT_RE = re.compile(
    r"""^(?:[-+]?0b[0-1_]+
    |[-+]?(?:0|[1-9][0-9_]*)
    |[-+]?0o[0-7_]+
    |[-+]?0x[0-9a-fA-F_]+)$""",
    re.X,
)
_FLOAT_RE = re.compile(
    r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+][0-9]+)?
    |\.[0-9][0-9_]*(?:[eE][-+][0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""",
    re.X,
)


class BenchYamlLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` with benchctl's rules (the module's docstring).

    Errors are ``ConfigError`` naming the file, line and column.
    """

    yaml_implicit_resolvers = {  # noqa: RUF012 (PyYAML's own class attribute)
        first: [
            (tag, _INT_RE if tag == _INT_TAG else _FLOAT_RE if tag == _FLOAT_TAG else rx)
            for tag, rx in resolvers
        ]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }

    def __init__(self, text: str, path: Path) -> None:
        super().__init__(text)
        self.name = str(path)  # marks (and so messages) name the file
        self.path = path
        self._depth = 0
        self._sizes: dict[int, int] = {}  # id(node) → nodes it expands to, aliases followed

    def fail(self, mark: yaml.Mark | None, message: str) -> ConfigError:
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        return ConfigError(f"{self.path}: not valid YAML: {where}{message}")

    # -- composer: depth and alias expansion ------------------------------------------------
    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node | None:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            node = super().compose_node(parent, index)
            if id(node) not in self._sizes:
                raise self.fail(
                    event.start_mark, f"alias *{event.anchor} is inside its own anchor (recursive)"
                )
            return node
        self._depth += 1
        if self._depth > MAX_YAML_DEPTH:
            raise self.fail(
                self.peek_event().start_mark,
                f"nested more than {MAX_YAML_DEPTH} levels deep; expected at most {MAX_YAML_DEPTH}",
            )
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        size = 1
        if isinstance(node, yaml.SequenceNode):
            size += sum(self._sizes[id(child)] for child in node.value)
        elif isinstance(node, yaml.MappingNode):
            size += sum(self._sizes[id(k)] + self._sizes[id(v)] for k, v in node.value)
        if size > MAX_YAML_NODES:
            raise self.fail(
                node.start_mark if node is not None else None,
                f"this node expands to {size} nodes through aliases; expected at most "
                f"{MAX_YAML_NODES} in a document",
            )
        self._sizes[id(node)] = size
        return node

    # -- constructor: duplicate keys, sexagesimal, any failure named --------------------------
    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, yaml.Mark] = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE_TAG:
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:
                    continue  # unhashable: PyYAML's own error below
                if first is not None:
                    raise self.fail(
                        key_node.start_mark,
                        f"duplicate key {shown_value(key)} (first at line {first.line + 1}); "
                        "expected each key once in a mapping",
                    )
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)

    def construct_object(self, node: yaml.Node, deep: bool = False) -> Any:
        try:
            return super().construct_object(node, deep=deep)
        except (ConfigError, yaml.YAMLError):
            raise
        except Exception as e:  # PyYAML's constructors raise ValueError, TypeError, ...
            raise self.fail(
                node.start_mark, f"cannot read {shown_value(node.value)} as {node.tag}: {e}"
            ) from None

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        if ":" in str(node.value):
            raise self.fail(node.start_mark, f"sexagesimal number {node.value!r} not supported")
        return int(super().construct_yaml_int(node))

    def construct_yaml_float(self, node: yaml.ScalarNode) -> float:
        if ":" in str(node.value):
            raise self.fail(node.start_mark, f"sexagesimal number {node.value!r} not supported")
        return float(super().construct_yaml_float(node))


BenchYamlLoader.add_constructor(_INT_TAG, BenchYamlLoader.construct_yaml_int)
BenchYamlLoader.add_constructor(_FLOAT_TAG, BenchYamlLoader.construct_yaml_float)


def _yaml_message(e: yaml.YAMLError, text: str) -> str:
    """One line from a PyYAML error: where, and what."""
    if isinstance(e, yaml.MarkedYAMLError):
        mark = e.problem_mark or e.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        what = e.problem or e.context or "syntax error"
        if e.problem and e.context:
            cm = e.context_mark
            at = f" at line {cm.line + 1}" if cm is not None and cm is not mark else ""
            what = f"{e.problem} ({e.context}{at})"
        msg = where + what
    elif isinstance(e, yaml.reader.ReaderError):
        line = text.count("\n", 0, max(0, e.position)) + 1
        char = e.character if isinstance(e.character, str) else chr(e.character)
        msg = (
            f"line {line}: character U+{ord(char):04X} at character offset {e.position}: "
            f"{e.reason}"
        )
    else:
        msg = str(e)
    return " ".join(msg.split())


def read_yaml(path: Path, what: str) -> Any:
    """Parse a YAML file by ``BenchYamlLoader``'s rules; ``ConfigError`` naming the file (and
    ``what`` it is), the line and the problem on any failure."""
    raw = read_input(path, what, ConfigError, MAX_YAML_BYTES)  # a regular file, bounded
    text = decode_utf8(raw, path, what, ConfigError)
    loader: BenchYamlLoader | None = None
    try:
        loader = BenchYamlLoader(text, path)  # the reader checks every character here
        return loader.get_single_data()
    except ConfigError:
        raise
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML: {_yaml_message(e, text)}") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid YAML: nested too deeply") from None
    finally:
        if loader is not None:
            loader.dispose()
