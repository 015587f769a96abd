"""Private module names: each built Python FMU imports only its own bundled code.

Python caches modules by name (``sys.modules``), and pythonfmu puts every
FMU's ``resources`` folder at the front of ``sys.path``. If the FMUs bundled
``flexarm`` (and the glue ``flexarm_fmu_base``, ...) under those names, the first
FMU loaded into a process would serve its copy to every later one: a controller
would then look for its gain files in the plant's folder, and two builds of one
FMU would share one slave module. So the build gives every top-level module
and package it bundles a name private to that FMU build,
``_<name>_<fmu>_<digest>`` (e.g. ``_flexarm_plant_3f2a9c01b7de``), where the
digest is the SHA-256 of the FMU's staged Python sources and data: two
different builds never share a name, and two FMUs never do.

:func:`rewrite_source` renames the imports of those modules in one source
file (``from flexarm.lqr import X`` becomes ``from _flexarm_<tag>.lqr import
X``) and, in the glue, any string literal that is exactly one of the names
(``sys.modules.get("flexarm")``); relative imports and everything else stay as they are. Only the
import statements' and literals' own text changes (located with :mod:`ast`), so
line numbers in tracebacks still match the project's sources.
"""

from __future__ import annotations

import ast
import hashlib
import io
import tokenize
from pathlib import Path

__all__ = ["private_name", "build_digest", "rewrite_source", "rewrite_tree"]


def private_name(name: str, fmu: str, digest: str) -> str:
    """The private module name of top-level module `name` in FMU `fmu` of build `digest`."""
    return f"_{name}_{fmu}_{digest[:12]}"


def build_digest(fmu: str, files: list[Path], root: Path) -> str:
    """SHA-256 over the FMU's name and its staged files (relative path and content), as hex."""
    h = hashlib.sha256(fmu.encode() + b"\0")
    for f in sorted(files, key=lambda p: p.relative_to(root).as_posix()):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def _renamed(module: str, names: dict[str, str]) -> str | None:
    top, dot, rest = module.partition(".")
    return names[top] + dot + rest if top in names else None


def rewrite_source(text: str, names: dict[str, str], where: str = "<source>", literals: bool = True) -> str:
    """`text` with the imports of (and, if `literals`, string literals equal to) the modules in `names` renamed.

    Parameters
    ----------
    text : str
        A Python source file.
    names : dict
        Top-level module name -> its private name.
    where : str
        The file, for error messages.
    literals : bool
        Also rename string literals equal to a name (the glue's ``sys.modules.get("flexarm")``); off for
        the library itself, whose literals are not module names (``Path.parts[:1] == ("flexarm",)``).

    Raises
    ------
    ValueError
        For ``import flexarm...`` without ``as`` (it binds the name ``flexarm`` in the module, which a
        renamed import would not): the bundled code uses ``from ... import`` or ``import ... as``.
    """
    tree = ast.parse(text, where)
    lines = text.splitlines(keepends=True)
    offsets = [0]
    for line in lines:
        offsets.append(offsets[-1] + len(line))
    edits: list[tuple[int, int, str]] = []  # (start, end, replacement) in character offsets

    def span(lineno: int, col: int) -> int:
        # ast columns are UTF-8 byte offsets
        return offsets[lineno - 1] + len(lines[lineno - 1].encode()[:col].decode())

    tokens = list(tokenize.generate_tokens(io.StringIO(text).readline))

    def name_tokens(node: ast.stmt, dotted: str) -> tuple[int, int]:
        """Character span of the dotted module name `dotted` inside the statement `node`."""
        start, end = span(node.lineno, node.col_offset), span(node.end_lineno, node.end_col_offset)
        first = dotted.split(".")[0]
        for tok in tokens:
            pos = offsets[tok.start[0] - 1] + tok.start[1]  # tokenize counts characters
            if tok.type == tokenize.NAME and tok.string == first and start <= pos < end and pos not in used:
                used.add(pos)
                return pos, pos + len(first)
        raise ValueError(f"{where}:{node.lineno}: cannot find module name {dotted!r} in the statement")

    used: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            new = _renamed(node.module, names)
            if new is not None:
                a, b = name_tokens(node, node.module)
                edits.append((a, b, names[node.module.split(".")[0]]))
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if _renamed(alias.name, names) is None:
                    continue
                if alias.asname is None:
                    raise ValueError(f"{where}:{node.lineno}: 'import {alias.name}' binds the name "
                                     f"{alias.name.split('.')[0]!r}; use 'from ... import' or 'import ... as'")
                a, b = name_tokens(node, alias.name)
                edits.append((a, b, names[alias.name.split(".")[0]]))
        elif literals and isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in names:
            a, b = span(node.lineno, node.col_offset), span(node.end_lineno, node.end_col_offset)
            quote = text[a]
            if quote not in "'\"" or text[b - 1] != quote:
                continue  # a prefixed or implicitly concatenated literal: not a module name
            edits.append((a, b, f"{quote}{names[node.value]}{quote}"))
    out = text
    for a, b, new in sorted(edits, reverse=True):
        out = out[:a] + new + out[b:]
    ast.parse(out, where)  # still valid Python
    return out


def rewrite_tree(files: list[Path], names: dict[str, str], literals: bool = True) -> None:
    """Rewrite every ``.py`` file in `files` in place (:func:`rewrite_source`)."""
    for f in files:
        if f.suffix == ".py":
            text = f.read_text(encoding="utf-8")
            new = rewrite_source(text, names, str(f), literals)
            if new != text:
                f.write_text(new, encoding="utf-8")
