"""Rows of numbers in the reference simulator's plain text inputs (wvl.txt, wi.txt):
:func:`number_rows`.

Comma-, semicolon- or whitespace-separated; blank lines and lines starting with ``#`` or ``%``
are skipped; the first remaining line may be a header of words (e.g. ``lambda,n,k``).
"""

from __future__ import annotations

__all__ = ["RowError", "number_rows"]


class RowError(ValueError):
    """A bad row: ``line_no`` (1-based), ``line`` (stripped) and ``problem`` (text)."""

    def __init__(self, line_no: int, line: str, problem: str):
        super().__init__(f"line {line_no} ({line!r}): {problem}")
        self.line_no, self.line, self.problem = line_no, line, problem


def number_rows(lines, columns: tuple[str, ...]):
    """(line_no, line, values) for every data row of ``lines``, each with len(columns) floats;
    a row with another count or a word raises RowError naming the columns."""
    header_allowed = True
    for line_no, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line[0] in "#%":
            continue
        fields = line.replace(",", " ").replace(";", " ").split()
        values = []
        for item in fields:
            try:
                values.append(float(item))
            except ValueError:
                values.append(None)
        if header_allowed and all(v is None for v in values):
            header_allowed = False  # a header line of column names
            continue
        header_allowed = False
        if len(values) != len(columns) or any(v is None for v in values):
            word = next((f for f, v in zip(fields, values) if v is None), None)
            problem = (f"{word!r} is not a number" if word is not None
                       else f"needs {len(columns)} values ({', '.join(columns)}), got {len(values)}")
            raise RowError(line_no, line, problem)
        yield line_no, line, values
