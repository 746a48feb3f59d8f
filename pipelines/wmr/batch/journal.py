"""The journal of a batch (``OUT/journal.jsonl``) and the test of a finished log.

The parent process appends one JSON line per finished run to a file opened with ``O_APPEND``
(a short write is continued until every byte is written): a batch killed at any moment leaves
whole lines, plus at most one cut line, which the reader ignores.  A run counts as done when
its journal line matches its inputs and its FMU, and its log ends with a ``result`` metadata
record (or the executor killed it: then the journal line, and the log recovered from what the
run had written, are all there is).
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from wmr.durable import write_all

JOURNAL = "journal.jsonl"


def log_complete(path: Path) -> bool:
    """Whether ``path`` is a finished MCAP log with a ``result`` metadata record.

    Reads the footer and the summary section only (about 1 ms), not the messages.
    """
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as stream:
            summary = make_reader(stream).get_summary()
    except Exception:  # missing, cut or damaged: not finished
        return False
    return summary is not None and any(m.name == "result" for m in summary.metadata_indexes)


class Journal:
    """Append-only record of finished runs.

    Parameters
    ----------
    path
        The ``journal.jsonl`` file (created on first append).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._checked = False

    def load(self) -> dict[str, dict[str, Any]]:
        """Rows by run id; the last whole line of an id wins, cut or garbled lines are skipped."""
        rows: dict[str, dict[str, Any]] = {}
        try:
            data = self.path.read_bytes()
        except FileNotFoundError:
            return rows
        for line in data.split(b"\n"):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except ValueError:
                continue
            if isinstance(row, dict) and isinstance(row.get("run_id"), str) \
                    and isinstance(row.get("record"), dict):
                rows[row["run_id"]] = row
        return rows

    def append(self, row: Mapping[str, Any]) -> None:
        """Append ``row`` as one line (a short write is continued, a full disk raises
        :class:`~wmr.errors.DiskFullError`)."""
        line = (json.dumps(row, allow_nan=False, separators=(",", ":")) + "\n").encode()
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        try:
            # a line that a previous batch cut short must not swallow this one
            if not self._checked:
                self._checked = True
                if os.fstat(fd).st_size and not self._ends_with_newline():
                    line = b"\n" + line
            write_all(fd, line, self.path)  # os.write may write less than asked: loop
        finally:
            os.close(fd)

    def _ends_with_newline(self) -> bool:
        with open(self.path, "rb") as f:
            f.seek(-1, os.SEEK_END)
            return f.read(1) == b"\n"


__all__ = ["JOURNAL", "Journal", "log_complete"]
