"""Reading files someone else may have written: checkpoints, datasets, protocol files, run folders, resume logs.

Every reader here takes the file as data and bounds what it costs:

* regular files only: a device, a FIFO or a directory (a symlink is followed, and what it points at checked) is
  refused before a byte is read, so ``/dev/zero`` cannot fill memory and a FIFO cannot hang the reader;
* the size is checked on the size the file states and on the bytes actually read (at most ``max_bytes`` + 1);
* JSON and YAML nesting is counted before a parser recurses into it, and a YAML document's aliases may not
  expand it past ``MAX_YAML_NODES``;
* every failure is one ``ValueError`` naming the file (and the line, where there is one).
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

#: The most a JSON or YAML document (a config, a card, a run's records) may hold, and a log of records (a
#: benchmark's episodes, a training's evaluations), bytes.
MAX_DOCUMENT_BYTES, MAX_LOG_BYTES = 16 << 20, 256 << 20
#: Bytes read at a time.
READ_BLOCK = 1 << 20
#: Nodes a YAML document may hold once its aliases are expanded (a 700-byte alias bomb expands to billions).
MAX_YAML_NODES = 100_000
#: How deep a JSON or YAML document may nest, unless a reader says otherwise.
MAX_DEPTH = 32
#: The YAML tokens that open and close a level of nesting.
OPENING_TOKENS = (
    yaml.BlockMappingStartToken,
    yaml.BlockSequenceStartToken,
    yaml.FlowMappingStartToken,
    yaml.FlowSequenceStartToken,
)
CLOSING_TOKENS = (yaml.BlockEndToken, yaml.FlowMappingEndToken, yaml.FlowSequenceEndToken)


def read_bytes(path: Path | str, max_bytes: int) -> bytes:
    """The bytes of regular file ``path``, at most ``max_bytes`` of them; ``ValueError`` naming the file if it is
    not a regular file (a device, a FIFO, a directory), cannot be read, or holds more."""
    path = Path(path)
    try:
        # Non-blocking: opening a FIFO for reading would otherwise wait for a writer.
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as error:
        raise ValueError(f"cannot read {path}: {error.strerror or error}") from None
    status = os.fstat(descriptor)
    if not stat.S_ISREG(status.st_mode) or status.st_size > max_bytes:
        os.close(descriptor)
        mode = status.st_mode
        kind = "a directory" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "a device or socket"
        if stat.S_ISREG(mode):
            raise ValueError(f"{path} holds {status.st_size} bytes, more than the {max_bytes} such a file may")
        raise ValueError(f"{path} is {kind}, not a regular file")
    chunks, size = [], 0
    with os.fdopen(descriptor, "rb") as handle:
        try:  # in blocks: a read of max_bytes at once would allocate all of it, however short the file
            while size <= max_bytes and (chunk := handle.read(min(READ_BLOCK, max_bytes + 1 - size))):
                chunks.append(chunk)
                size += len(chunk)
        except OSError as error:
            raise ValueError(f"cannot read {path}: {error.strerror or error}") from None
    if size > max_bytes:
        raise ValueError(f"{path} holds more than the {max_bytes} bytes such a file may")
    return b"".join(chunks)


def read_text(path: Path | str, max_bytes: int) -> str:
    """``read_bytes`` decoded as UTF-8 (``ValueError`` naming the file and the line of the first bad byte)."""
    data = read_bytes(path, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as error:
        line = data[: error.start].count(b"\n") + 1
        raise ValueError(f"{path} is not UTF-8 text (line {line})") from None


def json_depth(text: str) -> int:
    """How deep the JSON ``text`` nests (brackets and braces outside strings), counted without recursing."""
    depth = deepest = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            in_string, escaped = (in_string, False) if escaped else (char != '"', char == "\\")
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    return deepest


def parse_json(text: str, where: str, max_depth: int = MAX_DEPTH) -> Any:
    """The JSON value of ``text``; ``ValueError`` naming ``where`` (a file, a file and line) if it is not JSON
    or nests deeper than ``max_depth``.  Integers keep to 4300 digits (Python's own limit), named too."""
    deepest = json_depth(text)
    if deepest > max_depth:
        raise ValueError(f"{where} nests {deepest} levels deep, more than the {max_depth} such a file may")
    try:
        return json.loads(text)
    except (json.JSONDecodeError, RecursionError, ValueError) as error:
        raise ValueError(f"{where} is not valid JSON: {error}") from None


def read_json(path: Path | str, max_bytes: int, max_depth: int = MAX_DEPTH) -> Any:
    """The JSON value in file ``path`` (see the module docstring); ``ValueError`` naming the file."""
    return parse_json(read_text(path, max_bytes), str(path), max_depth)


def read_json_lines(path: Path | str, max_bytes: int, max_depth: int = MAX_DEPTH) -> Iterator[tuple[int, Any]]:
    """(line number, JSON value) of every non-empty line of file ``path``; ``ValueError`` naming the file and
    the line that is not JSON."""
    for number, line in enumerate(read_text(path, max_bytes).splitlines(), start=1):
        if line.strip():
            yield number, parse_json(line, f"{path} line {number}", max_depth)


def parse_yaml(text: str, where: str, max_depth: int = MAX_DEPTH) -> Any:
    """The value of YAML ``text`` (the safe subset); ``ValueError`` naming ``where`` if it is not YAML, nests
    deeper than ``max_depth`` or expands, through its aliases, past ``MAX_YAML_NODES`` nodes."""
    deepest = json_depth(text)  # flow nesting, counted at once: the scanner takes seconds over deep brackets
    if deepest > max_depth:
        raise ValueError(f"{where} nests {deepest} levels deep, more than the {max_depth} such a file may")
    try:
        depth = 0
        for token in yaml.scan(text, Loader=yaml.SafeLoader):  # the nesting, before the composer recurses
            if isinstance(token, OPENING_TOKENS):
                depth += 1
                if depth > max_depth:
                    raise ValueError(f"{where} nests more than the {max_depth} levels such a file may")
            elif isinstance(token, CLOSING_TOKENS):
                depth -= 1
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        if node is not None and _expanded_nodes(node) > MAX_YAML_NODES:
            raise ValueError(f"{where}: its aliases expand it past {MAX_YAML_NODES} nodes")
        return yaml.safe_load(text)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        line = f" (line {mark.line + 1})" if mark is not None else ""
        raise ValueError(f"{where} is not valid YAML{line}: {getattr(error, 'problem', None) or error}") from None
    except RecursionError:
        raise ValueError(f"{where} nests too deep to read") from None


def _expanded_nodes(root: yaml.Node) -> int:
    """How many nodes the YAML graph under ``root`` holds with every alias expanded (shared nodes counted once
    per reference), without recursing and stopping once past ``MAX_YAML_NODES``; a node that holds itself
    expands without end."""
    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        if id(node) in sizes:
            continue
        children = _children(node)
        if children_done or not children:
            sizes[id(node)] = min(1 + sum(sizes[id(child)] for child in children), MAX_YAML_NODES + 1)
            open_nodes.discard(id(node))
            continue
        if id(node) in open_nodes:  # reached again through its own children
            return MAX_YAML_NODES + 1
        open_nodes.add(id(node))
        stack.append((node, True))
        stack.extend((child, False) for child in children if id(child) not in sizes)
    return sizes[id(root)]


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [part for pair in node.value for part in pair]
    return []


def read_yaml(path: Path | str, max_bytes: int, max_depth: int = MAX_DEPTH) -> Any:
    """The YAML value in file ``path`` (see the module docstring); ``ValueError`` naming the file."""
    return parse_yaml(read_text(path, max_bytes), str(path), max_depth)
