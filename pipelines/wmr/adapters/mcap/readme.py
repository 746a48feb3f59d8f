"""The log's note to a viewer: what to run to see it as wmr's dashboard.

Rerun 0.41 opens an ``.mcap`` file with its own MCAP importer only: its external importers
(``rerun-importer-*`` executables on ``PATH``) are not called for a file type it supports
itself (``re_importer::import_file::import``, rerun-io/rerun issue 6530;
``tests/test_rerun_loader.py`` checks it), so ``rerun X.mcap`` cannot be made to show our
dashboard, and a blueprint given beside the file is ignored under its default settings
(docs/replay.md).  What its importer does show by itself is a ``std_msgs/msg/String``: a
``TextDocument``, which its default layout gives a panel of its own.  So every log of
``wmr run`` and ``wmr batch`` carries, at t = 0, one such message on :data:`README_TOPIC`
saying what the log is and what to run.  Foxglove shows it in its Raw Messages panel.

The message is ROS 2's ``std_msgs/msg/String`` in CDR (schema encoding ``ros2msg``, message
encoding ``cdr``): the only text message Rerun's MCAP importer turns into a document.  Its
CDR form is the 4-byte encapsulation header (little-endian CDR), the string's length with
its terminating NUL as a uint32, and the UTF-8 bytes with the NUL.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from typing import Final, Protocol

from numpy.typing import ArrayLike

#: The topic of the note.
README_TOPIC: Final = "/wmr/readme"
#: ROS 2's name of the message, and its definition (the ``ros2msg`` schema's data).
README_SCHEMA: Final = "std_msgs/msg/String"
README_SCHEMA_DATA: Final = b"string data"
README_SCHEMA_ENCODING: Final = "ros2msg"
README_MESSAGE_ENCODING: Final = "cdr"
#: CDR encapsulation header: representation CDR_LE (0x0001), options 0.
_CDR_LE: Final = b"\x00\x01\x00\x00"

#: The note: a paragraph a line (the viewer wraps them).  No file name in it: the same run
#: gives the same bytes whatever its log is called (Rerun names the recording after the
#: file, above the note).
README_TEXT: Final = (
    "A run log of wmr-cosim (its docs/replay.md says more).\n\n"
    "Rerun opens an MCAP file in its own layout: this note, and a 3-D view of /scene (the "
    "robot, its path and the goal). wmr's dashboard of the run (a top-down world with the "
    "robot, its path and goal; the errors, speeds, torques and PI terms against the "
    "simulation time in seconds) is:\n\n"
    "    wmr replay THIS_FILE.mcap\n\n"
    "Rerun cannot be made to open it that way by itself: it passes .mcap files to its own "
    "MCAP importer only, never to external importers. With Rerun's importer and wmr's "
    "panels:\n\n"
    "    wmr replay --blueprint-for THIS_FILE.mcap\n"
    "    rerun THIS_FILE.mcap THIS_FILE.rbl\n\n"
    "with Menu > Settings > \"Load files via Viewer catalog\" turned off (else the blueprint "
    "is ignored), and the time format \"seconds since Unix epoch\" (the log times are the "
    "simulation time from the start of the run).\n\n"
    "A real robot's log of the same manoeuvre beside it: wmr replay THIS_FILE.mcap "
    "ROBOT.mcap (aligned at the start of motion, the distance between the two paths "
    "plotted).\n"
)


def readme_message(text: str = README_TEXT) -> bytes:
    """``text`` as a CDR-encoded ``std_msgs/msg/String``."""
    data = text.encode("utf-8") + b"\x00"
    return _CDR_LE + struct.pack("<I", len(data)) + data


class NoteLog(Protocol):
    """What :func:`write_readme` needs of a log: the writer's ``write_messages`` with its
    encodings (:meth:`wmr.adapters.mcap.writer.RunLogWriter.write_messages`, and recovery's
    sink of the topics it makes)."""

    def write_messages(self, topic: str, schema_name: str, schema_data: bytes,
                       t_ns: ArrayLike, messages: Sequence[bytes], *,
                       schema_encoding: str = ..., message_encoding: str = ...) -> None:
        """Log serialised messages on a topic of their own."""
        ...


def write_readme(log: NoteLog) -> None:
    """Write the note (:data:`README_TEXT`) on :data:`README_TOPIC` at t = 0: the one way
    a log gets it, when the log writer closes a log and when recovery makes it."""
    log.write_messages(README_TOPIC, README_SCHEMA, README_SCHEMA_DATA, [0], [readme_message()],
                       schema_encoding=README_SCHEMA_ENCODING,
                       message_encoding=README_MESSAGE_ENCODING)


def read_readme(data: bytes) -> str:
    """The text of a CDR ``std_msgs/msg/String`` written by :func:`readme_message`.

    Raises
    ------
    ValueError
        Not little-endian CDR, or a length that does not fit the message.
    """
    if data[:4] != _CDR_LE or len(data) < 8:
        raise ValueError("not a little-endian CDR message")
    (n,) = struct.unpack_from("<I", data, 4)
    if n < 1 or 8 + n > len(data):
        raise ValueError(f"string length {n} does not fit a {len(data)}-byte message")
    return data[8:8 + n - 1].decode("utf-8")


__all__ = ["README_MESSAGE_ENCODING", "README_SCHEMA", "README_SCHEMA_DATA",
           "README_SCHEMA_ENCODING", "README_TEXT", "README_TOPIC", "NoteLog", "read_readme",
           "readme_message", "write_readme"]
