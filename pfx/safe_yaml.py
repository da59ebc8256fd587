"""Safe YAML reading, for configs and the data files they name (a wall map).

A config file is read by :func:`pfx.user_files.read_user_file`: only a regular file, at most
:data:`MAX_FILE_BYTES` (a pipe or a device is refused before it is opened).

Only YAML's plain data types are constructed (``yaml.SafeLoader``, reading YAML 1.2 floats): tags that would build
Python objects are errors. Duplicate keys are errors (plain PyYAML keeps the last one
silently). Aliases are allowed, but a document whose expansion would exceed
:data:`MAX_EXPANDED_NODES` nodes ("billion laughs") is refused before it is expanded.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from pfx.errors import ConfigError
from pfx.registry import with_article
from pfx.user_files import UnreadableFile, read_user_file

MAX_EXPANDED_NODES = 100_000


class ConfigLoader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats such as ``1e-3`` and ``3.0e5``.

    PyYAML follows YAML 1.1, where an exponent needs a dot and a sign (``1.0e+5``); otherwise
    ``1e-3`` would silently be the string '1e-3'.
    """


ConfigLoader.yaml_implicit_resolvers = {key: list(value) for key, value in
                                        yaml.SafeLoader.yaml_implicit_resolvers.items()}
ConfigLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))
MAX_FILE_BYTES = 10 * 1024 * 1024


def _mark_error(file: str, mark, reason: str, key: str | None = None) -> ConfigError:
    """A ConfigError at a PyYAML mark (0-based line and column), or at a 1-based (line, column) pair."""
    if mark is None:
        line = column = None
    elif isinstance(mark, tuple):
        line, column = mark
    else:
        line, column = mark.line + 1, mark.column + 1
    return ConfigError(reason, file=file, key=key, line=line, column=column)


# YAML's line breaks (YAML 1.1 and PyYAML's reader): the lines PyYAML's marks count.
_LINE_BREAK = re.compile(r"\r\n|[\r\n\x85\u2028\u2029]")
# Problems that PyYAML notices only at the next token, although what is missing (a ',', a
# closing bracket, a ':', anything at all) belongs right after the content before that token.
_NOTICED_LATE = re.compile(r"^expected ',' or |^could not find expected ':'|'<stream end>'")


def _without_comment(line: str) -> str:
    """The line without a trailing '# comment' (a '#' at the start or after a blank, outside quotes)."""
    quote = None
    for index, character in enumerate(line):
        if quote:
            if character == quote:
                quote = None
        elif character in "'\"":
            quote = character
        elif character == "#" and (index == 0 or line[index - 1] in " \t"):
            return line[:index]
    return line


def _unclosed_quote(error: yaml.MarkedYAMLError) -> bool:
    """A quoted scalar that runs to the end of the file (or to a '---'): its quote is not closed."""
    return (error.context_mark is not None and (error.context or "").startswith("while scanning a quoted scalar")
            and (error.problem or "").startswith("found unexpected"))


def _syntax_error_position(error: yaml.MarkedYAMLError, text: str) -> tuple[int, int] | None:
    """Where a user sees a YAML syntax error, as 1-based (line, column); None for no position.

    PyYAML's problem mark is where the parser *noticed* the problem: for an unclosed ``{``
    or a key without ``:`` that is the next token, often column 1 of the next line (or the
    end of the file, after trailing blank and comment lines). Then the position reported is
    just after the last non-blank, non-comment content before the mark: where the missing
    ``}`` or ``:`` belongs. A quote that is never closed runs to the end of the file, so the
    opening quote (the context mark) is reported. Otherwise, the problem mark: it points at
    the offending character (a tab, a misplaced ``:`` or ``-``).
    """
    problem, context = error.problem_mark, error.context_mark
    if problem is None:
        return (context.line + 1, context.column + 1) if context is not None else None
    if _unclosed_quote(error):
        return context.line + 1, context.column + 1
    lines = _LINE_BREAK.split(text)
    before_on_line = lines[problem.line][:problem.column] if problem.line < len(lines) else ""
    if _NOTICED_LATE.search(error.problem or "") and not before_on_line.strip():
        for index in range(min(problem.line, len(lines)) - 1, -1, -1):
            content = _without_comment(lines[index]).rstrip()
            if content.strip():
                return index + 1, len(content) + 1       # the column just after the content
    return problem.line + 1, problem.column + 1


def _check_tree(node: yaml.Node, file: str) -> None:
    """Refuse duplicate keys and documents whose aliases expand beyond the limit."""
    sizes: dict[int, int] = {}

    def expanded_size(current: yaml.Node, path: str, visiting: frozenset) -> int:
        identity = id(current)
        if identity in sizes:
            return sizes[identity]
        if identity in visiting:
            raise _mark_error(file, current.start_mark, "recursive YAML alias", path or None)
        visiting = visiting | {identity}
        size = 1
        if isinstance(current, yaml.MappingNode):
            seen: dict[Any, yaml.Node] = {}
            for key_node, value_node in current.value:
                key = key_node.value if isinstance(key_node, yaml.ScalarNode) else str(key_node.start_mark)
                child_path = f"{path}.{key}" if path else str(key)
                if key in seen:
                    raise _mark_error(file, key_node.start_mark, f"duplicate key {key!r}", child_path)
                seen[key] = key_node
                size += expanded_size(value_node, child_path, visiting) + 1
        elif isinstance(current, yaml.SequenceNode):
            for index, item in enumerate(current.value):
                size += expanded_size(item, f"{path}[{index}]", visiting)
        if size > MAX_EXPANDED_NODES:
            raise _mark_error(file, current.start_mark,
                              f"document expands to more than {MAX_EXPANDED_NODES} nodes "
                              "(YAML alias bomb?); refused", path or None)
        sizes[identity] = size
        return size

    expanded_size(node, "", frozenset())


def parse_yaml(text: str, file: str) -> Any:
    """Parse one YAML document safely; errors carry file, line and column."""
    loader = ConfigLoader(text)
    try:
        if not loader.check_node():
            raise ConfigError("file is empty (expected a YAML mapping)", file=file)
        node = loader.get_node()
        if loader.check_node():
            raise _mark_error(file, loader.peek_event().start_mark,
                              "more than one YAML document (one experiment per file)")
        _check_tree(node, file)
        return loader.construct_document(node)
    except yaml.MarkedYAMLError as error:
        mark = error.problem_mark or error.context_mark
        reason = (error.problem or error.context or "invalid YAML").strip()
        if isinstance(error, yaml.constructor.ConstructorError) and "tag" in reason:
            reason = f"YAML tag not allowed: {reason}"
        elif isinstance(error, yaml.constructor.ConstructorError):
            reason = f"YAML error: {reason}"
        else:                           # scanner, parser, composer: where the user sees the problem
            mark = _syntax_error_position(error, text)
            reason = f"YAML syntax error: {reason}"
            if _unclosed_quote(error):
                reason += " (the quote opened here is not closed)"
            opened = error.context_mark
            if error.context in ("while parsing a flow mapping", "while parsing a flow sequence") \
                    and mark is not None and mark[0] != opened.line + 1:
                # the opening bracket may be lines away from where the problem shows
                reason += (f" (in the {error.context[len('while parsing a '):]} opened at "
                           f"line {opened.line + 1}, column {opened.column + 1})")
        raise _mark_error(file, mark, reason) from None
    except yaml.YAMLError as error:
        raise ConfigError(f"YAML error: {error}", file=file) from None
    finally:
        loader.dispose()


def load_config_file(path: str | Path) -> dict:
    """Read a config file: a YAML mapping, checked as described in the module docstring."""
    file = str(path)
    try:
        data = read_user_file(path, MAX_FILE_BYTES)
    except UnreadableFile as error:
        raise ConfigError("no such file" if error.missing else error.reason, file=file) from None
    if b"\x00" in data:
        raise ConfigError("binary file, not YAML text", file=file)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise ConfigError(f"not UTF-8 text (byte {error.start})", file=file) from None
    document = parse_yaml(text, file)
    if not isinstance(document, dict):
        kind = "a list" if isinstance(document, list) else with_article(type(document).__name__)
        if document is None:
            raise ConfigError("file holds no settings (expected a YAML mapping)", file=file)
        raise ConfigError(f"top level must be a mapping of sections, not {kind}", file=file)
    return document
