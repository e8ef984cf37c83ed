"""YAML text read strictly, for the config and the scene files: safe (no Python objects), a
duplicate key refused (PyYAML keeps the last), nesting and alias expansion bounded; any
failure a ConfigError naming the file, the line and the column."""

from __future__ import annotations

from typing import Any

import yaml

from kali_daemons.core.errors import ConfigError

MAX_YAML_DEPTH = 32  # the deepest real config is 4 levels
MAX_YAML_NODES = 100_000  # after alias expansion; the default config has ~600


def parse_yaml(text: str, source: str) -> Any:
    """The document in ``text``; ConfigError naming ``source`` if it does not parse."""
    try:
        return yaml.load(text, Loader=StrictLoader)  # a SafeLoader
    except yaml.MarkedYAMLError as exc:
        raise ConfigError(f"{source}: {_error_text(exc)}") from None
    except yaml.reader.ReaderError as exc:  # a control character or bad code point
        line = text.count("\n", 0, exc.position) + 1
        code = exc.character if isinstance(exc.character, int) else ord(exc.character)
        reason = f"character U+{code:04X} is not allowed in YAML"
        raise ConfigError(f"{source}: line {line}: YAML does not parse: {reason}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: YAML does not parse: {exc}") from None


class StrictLoader(yaml.SafeLoader):
    """A SafeLoader that rejects duplicate mapping keys (PyYAML silently keeps the last),
    nesting deeper than MAX_YAML_DEPTH (Python's recursion limit would end it with a
    traceback) and aliases expanding to more than MAX_YAML_NODES nodes ("billion laughs":
    PyYAML shares aliased objects, but every walk of the document, an error message's
    rendering of a value included, would visit each of the 10**9 leaves)."""

    _depth = 0

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node:
        if self._depth >= MAX_YAML_DEPTH:
            raise yaml.composer.ComposerError(
                None,
                None,
                f"nested deeper than {MAX_YAML_DEPTH} levels",
                self.peek_event().start_mark,
            )
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def compose_document(self) -> yaml.Node:
        node = super().compose_document()
        sizes: dict[int, int] = {}  # id(node) -> expanded size: an alias is its anchor's node

        def size(n: yaml.Node) -> int:  # depth bounded by MAX_YAML_DEPTH
            if id(n) not in sizes:
                if isinstance(n, yaml.SequenceNode):
                    children = n.value
                elif isinstance(n, yaml.MappingNode):
                    children = [c for pair in n.value for c in pair]
                else:
                    children = []
                total = 1
                for c in children:
                    total += size(c)
                    if total > MAX_YAML_NODES:
                        raise yaml.composer.ComposerError(
                            None,
                            None,
                            f"aliases expand to more than {MAX_YAML_NODES} nodes",
                            n.start_mark,
                        )
                sizes[id(n)] = total
            return sizes[id(n)]

        if node is not None:
            size(node)
        return node

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict[Any, Any]:
        seen: set[tuple[str, str]] = set()
        if isinstance(node, yaml.MappingNode):
            for key_node, _ in node.value:
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag.endswith(":merge"):
                    continue
                ident = (key_node.tag, key_node.value)
                if ident in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {key_node.value!r}", key_node.start_mark
                    )
                seen.add(ident)
        return super().construct_mapping(node, deep=deep)


def _error_text(exc: yaml.MarkedYAMLError) -> str:
    """``line L, column C: YAML does not parse: <problem>`` (1-based, as editors count)."""
    mark = exc.problem_mark or exc.context_mark
    problem = exc.problem or exc.context or "syntax error"
    if mark is None:
        return f"YAML does not parse: {problem}"
    return f"line {mark.line + 1}, column {mark.column + 1}: YAML does not parse: {problem}"
