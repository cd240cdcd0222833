"""Submissions whose code is the same once comments, layout and names are set aside.

Identical bytes (the sheet's ``same_files_as``) miss the commonest copy: the same code with
a comment changed, reformatted, or its variables renamed. :func:`similar_groups` reads each
submission's three graded files (the one intake; a missing file is its stub), normalizes
them (:func:`normalized`: parsed and written back by Python's own ``ast``, so comments,
docstrings and layout are dropped, then tokenized with every name that is not a keyword
replaced by one placeholder; other strings and the numbers kept) and groups the submissions
whose normalized files are equal. The untouched stubs are left out, and so is a group whose
code of its own (the tokens that differ from the stubs) is shorter than
:data:`MIN_OWN_TOKENS`: a one-line answer everyone writes alike is no sign.
Nothing here is a verdict: the class page lists the groups for the lecturer to look at.
"""

from __future__ import annotations

import ast
import difflib
import functools
import hashlib
import io
import keyword
import tokenize

MIN_OWN_TOKENS = 30
"""Fewest tokens of a group's own code (not the stubs') for it to be listed."""
_DROPPED = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT}


def _without_docstrings(source: bytes) -> bytes:
    """The source as Python's parser reads it, without its docstrings (a string alone on its
    line), written back by ``ast.unparse`` (one layout); the source itself when it does not
    parse."""
    try:
        tree = ast.parse(source)
    except (SyntaxError, ValueError):
        return source
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(body, list):
            kept = [
                n
                for n in body
                if not (
                    isinstance(n, ast.Expr)
                    and isinstance(n.value, ast.Constant)
                    and isinstance(n.value.value, str)
                )
            ]
            node.body = kept or [ast.Pass()]
    return ast.unparse(tree).encode()


def normalized(source: bytes) -> list[str]:
    """The source's tokens without comments, docstrings and layout, each non-keyword name as
    ``N`` (the raw text's words when it does not tokenize, e.g. a syntax error)."""
    try:
        tokens = list(tokenize.tokenize(io.BytesIO(_without_docstrings(source)).readline))
    except (tokenize.TokenError, SyntaxError, UnicodeDecodeError):
        return source.decode("utf-8", "replace").split()
    out = []
    for token in tokens:
        if token.type in _DROPPED or token.type in (tokenize.ENCODING, tokenize.ENDMARKER):
            continue
        if token.type == tokenize.NAME and not keyword.iskeyword(token.string):
            out.append("N")
        else:
            out.append(token.string)
    return out


@functools.cache
def _stub_tokens() -> dict[str, tuple[str, ...]]:
    from doorlab.pset.classroom.regrade import _stubs

    return {rel: tuple(normalized(data)) for rel, data in _stubs().items()}


def _own_tokens(tokens: list[str], stub: tuple[str, ...]) -> int:
    """How many of ``tokens`` are not the stub's (inserted or replaced)."""
    matcher = difflib.SequenceMatcher(None, stub, tokens, autojunk=False)
    return sum(j2 - j1 for op, _, _, j1, j2 in matcher.get_opcodes() if op != "equal")


def fingerprint(files: dict[str, bytes]) -> tuple[str, int] | None:
    """A submission's normalized code's SHA-256 and how many of its tokens are its own (None
    for the untouched stubs)."""
    stubs = _stub_tokens()
    digest = hashlib.sha256()
    own = 0
    for rel, stub in stubs.items():
        tokens = normalized(files[rel]) if rel in files else list(stub)
        digest.update(rel.encode() + b"\0" + " ".join(tokens).encode() + b"\0")
        if tuple(tokens) != stub:
            own += _own_tokens(tokens, stub)
    return None if own == 0 else (digest.hexdigest(), own)


def similar_groups(submissions) -> list[dict]:
    """Groups of two or more submissions with the same normalized code (see the module
    docstring): ``{"submissions": [ids], "own_tokens": n}``, largest first."""
    from doorlab.errors import OutputError
    from doorlab.pset.grading.grader import take_files

    by_print: dict[str, list[str]] = {}
    own: dict[str, int] = {}
    for submission in submissions:
        if submission.path is None:
            continue
        try:
            files, intake = take_files(submission.path)
        except OutputError:
            continue
        if intake.refused is not None or not files:
            continue
        found = fingerprint(files)
        if found is None:
            continue
        by_print.setdefault(found[0], []).append(submission.id)
        own[found[0]] = found[1]
    groups = [
        {"submissions": ids, "own_tokens": own[key]}
        for key, ids in by_print.items()
        if len(ids) > 1 and own[key] >= MIN_OWN_TOKENS
    ]
    return sorted(groups, key=lambda g: (-len(g["submissions"]), g["submissions"]))
