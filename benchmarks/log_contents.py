"""Whether two writers' logs hold the same things, whatever their bytes: every message (topic,
log and publish time, sequence, data, schema name and encoding, message encoding), every
metadata record, every attachment and the header, read by the ``mcap`` library with every CRC
checked, and the rows ``wmr.read_log`` reads back.

For a change of the log writer that changes the bytes (the chunks' compression, their layout)
but not what a log says: write the same logs with the code before and after (the same paths:
the ``result`` record names its log) into two folders, then

``PYTHONPATH=pipelines python benchmarks/log_contents.py BEFORE_DIR AFTER_DIR``

compares each ``*.mcap`` of ``BEFORE_DIR`` with its namesake in ``AFTER_DIR``, a line each;
exit status 1 if any differs.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from mcap.reader import make_reader


def contents(path: Path) -> tuple[dict[str, list[tuple[Any, ...]]], list[Any], list[Any], Any]:
    """A log's messages by topic (in log-time then sequence order), metadata records,
    attachments and header fields."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        messages: dict[str, list[tuple[Any, ...]]] = {}
        for schema, channel, m in reader.iter_messages(log_time_order=False):
            messages.setdefault(channel.topic, []).append(
                (m.log_time, m.publish_time, m.sequence, m.data,
                 schema.name if schema else None, schema.encoding if schema else None,
                 channel.message_encoding))
        for rows in messages.values():
            rows.sort(key=lambda r: (r[0], r[2]))
        metadata = [(m.name, m.metadata) for m in reader.iter_metadata()]
        attachments = [(a.name, a.media_type, a.data) for a in reader.iter_attachments()]
        header = reader.get_header()
    return messages, metadata, attachments, (header.profile, header.library)


def main(before: Path, after: Path) -> int:
    import wmr

    differ = 0
    for a in sorted(before.glob("*.mcap")):
        b = after / a.name
        ca, cb = contents(a), contents(b)
        parts = dict(zip(("messages", "metadata", "attachments", "header"),
                         (x == y for x, y in zip(ca, cb, strict=True)), strict=True))
        rows = wmr.read_log(a).signals.equals(wmr.read_log(b).signals)
        n = sum(len(v) for v in ca[0].values())
        same = all(parts.values()) and rows
        differ += not same
        print(f"{a.name}: {'same' if same else 'DIFFERENT'} ({n} messages; "
              + ", ".join(f"{k} {'same' if v else 'differ'}" for k, v in parts.items())
              + f", read_log rows {'same' if rows else 'differ'}; "
              f"{a.stat().st_size} and {b.stat().st_size} bytes)")
        if not parts["messages"]:
            for topic in sorted(set(ca[0]) | set(cb[0])):
                if ca[0].get(topic) != cb[0].get(topic):
                    print(f"  {topic}: {len(ca[0].get(topic, []))} and "
                          f"{len(cb[0].get(topic, []))} messages, not the same")
    return 1 if differ else 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
