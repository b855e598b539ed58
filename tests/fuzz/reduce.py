"""Shrink a failing Buzz program to a small reproduction (delta debugging on lines/tokens).

`reduce_source(source, still_fails)` repeatedly deletes chunks of lines, then single
lines, then balanced `{...}` / `(...)` groups and whitespace-separated tokens, keeping
each deletion after which `still_fails(candidate)` is true. Candidates that do not
compile simply fail the predicate.
"""

from __future__ import annotations

import re
from collections.abc import Callable

_TOKEN = re.compile(r"""\s+|"(?:[^"\\]|\\.)*"|'(?:[^'\\]|\\.)*'|[A-Za-z0-9_.]+|.""")


def _ddmin_lines(lines: list[str], test: Callable[[list[str]], bool]) -> list[str]:
    n = 2
    while len(lines) >= 2:
        chunk = max(1, len(lines) // n)
        removed = False
        for start in range(0, len(lines), chunk):
            cand = lines[:start] + lines[start + chunk :]
            if cand and test(cand):
                lines = cand
                n = max(n - 1, 2)
                removed = True
                break
        if not removed:
            if chunk == 1:
                break
            n = min(len(lines), n * 2)
    return lines


def _groups(text: str) -> list[tuple[int, int]]:
    """Spans of balanced (...), {...} and [...] groups, largest first."""
    spans = []
    stack: list[tuple[str, int]] = []
    pairs = {")": "(", "}": "{", "]": "["}
    in_str: str | None = None
    i = 0
    while i < len(text):
        c = text[i]
        if in_str:
            if c == "\\":
                i += 2
                continue
            if c == in_str:
                in_str = None
        elif c in "\"'":
            in_str = c
        elif c in "({[":
            stack.append((c, i))
        elif c in ")}]" and stack and stack[-1][0] == pairs[c]:
            _, start = stack.pop()
            spans.append((start, i + 1))
        i += 1
    spans.sort(key=lambda s: s[0] - s[1])
    return spans


def reduce_source(source: str, still_fails: Callable[[str], bool], *, rounds: int = 4) -> str:
    """A smaller source for which `still_fails` holds (`source` itself must satisfy it)."""

    def lines_ok(lines: list[str]) -> bool:
        return still_fails("\n".join(lines) + "\n")

    best = source
    for _ in range(rounds):
        before = best
        best = "\n".join(_ddmin_lines(best.splitlines(), lines_ok)) + "\n"
        # Balanced groups: try replacing each with an empty/simple group.
        changed = True
        while changed:
            changed = False
            for start, end in _groups(best):
                inner = best[start:end]
                for repl in (inner[0] + inner[-1], "(1)", "(nil)", "{}"):
                    if repl == inner or (inner[0] == "{" and repl in ("(1)", "(nil)")):
                        continue
                    cand = best[:start] + repl + best[end:]
                    if still_fails(cand):
                        best = cand
                        changed = True
                        break
                if changed:
                    break
        # Tokens: try deleting each, or replacing literals by simpler ones.
        tokens = _TOKEN.findall(best)
        i = 0
        while i < len(tokens):
            tok = tokens[i]
            if tok.isspace():
                i += 1
                continue
            for repl in ("", "1", "0", "nil", "x"):
                if repl == tok:
                    continue
                cand_tokens = tokens[:i] + ([repl] if repl else []) + tokens[i + 1 :]
                if still_fails("".join(cand_tokens)):
                    tokens = cand_tokens
                    break
            else:
                i += 1
                continue
            if not repl:
                continue
            i += 1
        best = "".join(tokens)
        if best == before:
            break
    return best
