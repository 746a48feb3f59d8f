"""The one door for every archive we open: FMUs, SSP packages, and the FMUs inside packages.

An archive is a file a stranger made.  :func:`open_archive` checks every member *before*
anything is written: its name (no absolute, ``..``, drive, backslash, control-character or
empty path; no two names that land on the same file, also on a case-insensitive file system;
no file under another file), its kind (regular files and folders only: no symbolic link, device,
FIFO or Windows reparse point in the external attributes), its encryption and compression
(stored or deflate, what FMI and SSP allow), the member count and the size of the central
directory.  :meth:`CheckedArchive.extract` and :meth:`CheckedArchive.read` then count the bytes
*while inflating* (a header's sizes are not trusted) against a per-member and a total budget,
and check every CRC.  Files are created with ``O_CREAT | O_EXCL | O_NOFOLLOW`` in a folder the
caller made, so nothing is ever written outside it, through a link, or over another member.

A master we did not write (libcosim) is only ever given a folder or a file we extracted and
checked ourselves (:mod:`wmr.adapters.ssp.package`), never the stranger's archive: its own zip
reader may not read the same members as Python's.

XML read from an archive goes through :func:`parse_xml`: bounded size and depth, and no
document type declaration, hence no entity (internal, external or parameter) is ever expanded.
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import stat
import struct
import xml.etree.ElementTree as ET
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import BinaryIO, Final
from xml.parsers import expat

from wmr.infra.errors import ConfigError, FmuError
from wmr.infra.inputs import MAX_ARCHIVE_BYTES, open_input, sha256_input

MiB: Final = 1 << 20
#: Default bounds of one archive (an FMU, or a package with the FMUs inside it).
MAX_MEMBERS: Final = 10_000
MAX_UNCOMPRESSED_BYTES: Final = 512 * MiB
#: The central directory is read into memory before any member can be counted: bounded first.
MAX_CENTRAL_DIRECTORY_BYTES: Final = 16 * MiB
#: A member name longer than this is refused (file systems refuse 255-byte names anyway).
MAX_NAME_CHARS: Final = 1024
#: XML documents: an SSP's SSD and SSVs (we parse them into memory), an FMU's model
#: description (fmpy and the masters do), each bounded while it inflates; nesting depth.
MAX_XML_BYTES: Final = 32 * MiB
#: fmpy parses the model description whole with lxml, at about 25 bytes of memory per byte
#: of XML (a 62.5 MiB one peaked at 1.54 GB): ours are a few kB, large real ones (thousands
#: of variables) about 10 MB, so 16 MiB keeps every real one and the parse under ~0.4 GB.
MAX_MODEL_DESCRIPTION_BYTES: Final = 16 * MiB
MAX_XML_DEPTH: Final = 256
_CHUNK: Final = MiB
_ALLOWED_COMPRESSION: Final = (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED)
_WINDOWS_REPARSE_POINT: Final = 0x400  # FILE_ATTRIBUTE_REPARSE_POINT: a Windows link
#: Members that masters parse as FMI or SSP XML, checked by :class:`XmlGuard` as they inflate.
_XML_SUFFIXES: Final = (".ssd", ".ssv", ".ssm")
_MODEL_DESCRIPTION: Final = "modelDescription.xml"
#: FMI 2.0 and 3.0: a ``modelIdentifier`` is a C identifier (it names the library under
#: ``binaries/<platform>/`` and prefixes its functions); bounded, as file names are.
MAX_IDENTIFIER_CHARS: Final = 200
_IDENTIFIER: Final = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: The interface elements of a model description whose ``modelIdentifier`` names a library.
_INTERFACES: Final = ("CoSimulation", "ModelExchange", "ScheduledExecution")
_EOCD: Final = b"PK\x05\x06"
_ZIP64_LOCATOR: Final = b"PK\x06\x07"


@dataclass
class Budget:
    """What is left to inflate: shared by an archive and the archives inside it, so that a
    package of many nested FMUs cannot multiply the bound."""

    members: int = MAX_MEMBERS
    total_bytes: int = MAX_UNCOMPRESSED_BYTES
    member_bytes: int = MAX_UNCOMPRESSED_BYTES

    def __post_init__(self) -> None:
        self.total_limit = self.total_bytes  # for messages: total_bytes counts down


def _show(name: str) -> str:
    """A member name for a one-line message: quoted, escaped, cut when long."""
    text = repr(name)
    return text if len(text) <= 120 else f"{text[:100]}... ({len(name)} characters)"


def _refuse(where: str, problem: str) -> FmuError:
    return FmuError(f"{where}: {problem}: refused")


def _central_directory(fp: BinaryIO) -> tuple[int, int] | None:
    """``(entries, size in bytes)`` of the central directory, from the end record (and its
    ZIP64 twin), before :mod:`zipfile` reads it all into memory; ``None`` if no end record
    (:mod:`zipfile` then says the file is no zip)."""
    fp.seek(0, os.SEEK_END)
    size = fp.tell()
    tail_bytes = min(size, 22 + 0xFFFF)  # the end record and its longest comment
    fp.seek(size - tail_bytes)
    tail = fp.read(tail_bytes)
    at = tail.rfind(_EOCD)
    if at < 0 or at + 22 > len(tail):
        return None
    entries, cd_size = struct.unpack("<HI", tail[at + 10:at + 16])
    if (entries == 0xFFFF or cd_size == 0xFFFFFFFF) and at >= 20 and \
            tail[at - 20:at - 16] == _ZIP64_LOCATOR:
        (offset,) = struct.unpack("<Q", tail[at - 12:at - 4])
        if offset + 56 <= size:
            fp.seek(offset)
            record = fp.read(56)
            if record[:4] == b"PK\x06\x06":
                entries, cd_size = struct.unpack("<QQ", record[32:48])
    return entries, cd_size


def _check_name(name: str, where: str) -> PurePosixPath:
    """The member's path, relative and inside the extraction folder, or a refusal."""
    shown = _show(name)
    if not name or len(name) > MAX_NAME_CHARS:
        raise _refuse(where, f"member {shown} has an empty or over-long name")
    if "\\" in name:
        raise _refuse(where, f"member {shown} has a backslash in its path (a Windows "
                             "separator: it may be written outside the folder)")
    if any(ord(c) < 0x20 or c == "\x7f" for c in name):
        raise _refuse(where, f"member {shown} has a control character in its name")
    pure = PurePosixPath(name)
    if name.startswith("/") or pure.is_absolute():
        raise _refuse(where, f"member {shown} is an absolute path (would be written outside "
                             "the folder)")
    if ".." in pure.parts:
        raise _refuse(where, f"member {shown} contains '..' (would be written outside the "
                             "folder)")
    if ":" in name:
        raise _refuse(where, f"member {shown} has a ':' in its path (a drive or a Windows "
                             "stream)")
    if not pure.parts:
        raise _refuse(where, f"member {shown} names the folder itself")
    return pure


def _check_kind(info: zipfile.ZipInfo, where: str) -> None:
    shown = _show(info.filename)
    mode = info.external_attr >> 16
    kind = stat.S_IFMT(mode)
    if info.create_system == 3 and kind not in (0, stat.S_IFREG, stat.S_IFDIR):
        what = "a symbolic link" if kind == stat.S_IFLNK else f"a special file (mode {mode:o})"
        raise _refuse(where, f"member {shown} is {what}")
    if info.external_attr & _WINDOWS_REPARSE_POINT:
        raise _refuse(where, f"member {shown} is a Windows reparse point (a link)")
    if info.flag_bits & 0x1:
        raise _refuse(where, f"member {shown} is encrypted")
    if info.compress_type not in _ALLOWED_COMPRESSION:
        raise _refuse(where, f"member {shown} uses compression method {info.compress_type} "
                             "(FMI and SSP archives are stored or deflated)")


class CheckedArchive:
    """A zip archive whose member list passed every check; read with :meth:`read` and
    :meth:`extract`, which count inflated bytes against the :class:`Budget`."""

    def __init__(self, zf: zipfile.ZipFile, fp: io.BufferedReader, where: str,
                 budget: Budget) -> None:
        self._zf = zf
        self._fp = fp
        self.where = where
        self.budget = budget
        self.members: dict[str, zipfile.ZipInfo] = {}  # file members by normalised name
        self.folders: set[str] = set()
        seen: dict[str, str] = {}
        infos = zf.infolist()
        if len(infos) > budget.members:
            raise _refuse(where, f"{len(infos)} members, more than {budget.members}")
        budget.members -= len(infos)
        for info in infos:
            pure = _check_name(info.filename, where)
            _check_kind(info, where)
            norm = pure.as_posix()
            key = norm.casefold()  # two names for one file on macOS and Windows
            if key in seen:
                raise _refuse(where, f"members {_show(seen[key])} and {_show(info.filename)} "
                                     "are the same file (a duplicate)")
            seen[key] = info.filename
            if info.is_dir():
                self.folders.add(norm)
            else:
                if info.file_size > budget.member_bytes:
                    raise _refuse(where, f"member {_show(info.filename)} unpacks to more than "
                                         f"{budget.member_bytes} bytes")
                self.members[norm] = info
        file_keys = {name.casefold() for name in self.members}
        for norm in [*self.members, *self.folders]:
            for parent in PurePosixPath(norm).parents:
                if parent.as_posix().casefold() in file_keys:
                    raise _refuse(where, f"member {_show(norm)} is under "
                                         f"{_show(parent.as_posix())}, which is a file")

    def chunks(self, name: str, limit: int | None = None, guard: XmlGuard | None = None,
               charge: bool = True) -> Iterator[bytes]:
        """The bytes of member ``name`` (:exc:`KeyError` if none), chunk by chunk, counted
        against the budget (and ``limit``) as they come out of the decompressor; an FMI or SSP
        document
        (``modelDescription.xml``, ``.ssd``, ``.ssv``, ``.ssm``) is also checked by
        :class:`XmlGuard` as it streams."""
        info = self.members.get(name)
        if info is None:
            raise KeyError(name)
        count = 0
        cap = self.budget.member_bytes if limit is None else min(limit, self.budget.member_bytes)
        if name == _MODEL_DESCRIPTION or name.endswith(_XML_SUFFIXES):
            cap = min(cap, MAX_MODEL_DESCRIPTION_BYTES if name == _MODEL_DESCRIPTION
                      else MAX_XML_BYTES)
            guard = guard if guard is not None else XmlGuard(f"{self.where}: {name}")
        try:
            with self._zf.open(info) as stream:
                while chunk := stream.read(_CHUNK):
                    count += len(chunk)
                    if charge:  # not again for the bytes a check already counted
                        self.budget.total_bytes -= len(chunk)
                    if count > cap:
                        raise _refuse(self.where, f"member {_show(name)} unpacks to more "
                                                  f"than {cap} bytes")
                    if self.budget.total_bytes < 0:
                        raise _refuse(self.where, "unpacks to more than "
                                                  f"{self.budget.total_limit} bytes in all")
                    if guard is not None:
                        guard.feed(chunk)
                    yield chunk
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError,
                NotImplementedError, RuntimeError) as exc:
            raise _refuse(self.where, f"member {_show(name)} is damaged ({exc})") from exc
        if guard is not None:
            guard.close()

    def sha256(self) -> str:
        """SHA-256 of the archive file as opened (the bytes that were checked)."""
        self._fp.seek(0)  # zipfile seeks to each member before reading it
        return hashlib.file_digest(self._fp, "sha256").hexdigest()

    def read(self, name: str, limit: int | None = None) -> bytes:
        """Member ``name`` in memory (at most ``limit`` bytes, else refused).

        Raises
        ------
        KeyError
            No such member.
        FmuError
            Over its bound, or damaged.
        """
        return b"".join(self.chunks(name, limit))

    def check(self) -> None:
        """Inflate every member without keeping it: sizes and CRCs are then known good."""
        for name in self.members:
            for _ in self.chunks(name):
                pass

    def extract(self, dest: Path) -> Path:
        """:meth:`check` every member, then write them under ``dest`` (a folder the caller
        made and nobody else writes): a bomb never reaches the disk.  Files are created
        ``O_EXCL | O_NOFOLLOW``, never through a link."""
        self.check()
        for folder in sorted(self.folders):
            (dest / folder).mkdir(parents=True, exist_ok=True)
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
        for name in self.members:
            target = dest / name
            target.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(target, flags, 0o644)
            with open(fd, "wb") as out:
                for chunk in self.chunks(name, limit=self.members[name].file_size,
                                         charge=False):
                    out.write(chunk)
        return dest


@contextmanager
def open_archive(path: str | os.PathLike[str], what: str = "FMU",
                 budget: Budget | None = None, where: str | None = None
                 ) -> Iterator[CheckedArchive]:
    """Open the zip archive ``path`` and check its member list (nothing is inflated yet).

    Parameters
    ----------
    path
        The archive.
    what
        What it is, for messages (``"FMU"``, ``"SSP package"``).
    budget
        What may still be inflated (shared with the archive that holds this one); default a
        fresh :class:`Budget`.
    where
        How messages name the archive (``"fig11.ssp: resources/robot.fmu"``); default
        ``path``.

    Raises
    ------
    FmuError
        The file is missing or no zip archive, or a member is refused (one line naming the
        file, the member and what is wrong).
    """
    p = Path(path)
    label = where or str(p)
    budget = budget if budget is not None else Budget()
    try:  # a FIFO, a device or a folder refused without blocking; closed by the with below
        fp = open_input(p, label, max_bytes=MAX_ARCHIVE_BYTES, what=f"an {what}",
                        fix=f"give an {what} file")
    except FileNotFoundError:
        hint = " (build one with 'wmr fmu build')" if what == "FMU" else ""
        raise FmuError(f"{label}: no such {what} file{hint}") from None
    except ConfigError as exc:
        raise FmuError(str(exc)) from None
    with fp:
        try:
            directory = _central_directory(fp)
        except (OSError, struct.error) as exc:
            raise FmuError(f"{label} is not an {what} (not a zip archive: {exc})") from exc
        if directory is not None:
            entries, cd_bytes = directory
            if entries > budget.members:
                raise _refuse(label, f"{entries} members, more than {budget.members}")
            if cd_bytes > MAX_CENTRAL_DIRECTORY_BYTES:
                raise _refuse(label, f"its central directory is {cd_bytes} bytes, more than "
                                     f"{MAX_CENTRAL_DIRECTORY_BYTES}")
        fp.seek(0)
        try:
            zf = zipfile.ZipFile(fp)
        except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
            raise FmuError(f"{label} is not an {what} (not a zip archive: {exc})") from exc
        with zf:
            yield CheckedArchive(zf, fp, label, budget)


def check_archive(path: Path, budget: Budget | None = None, where: str | None = None
                  ) -> list[str]:
    """Check the FMU at ``path`` through :func:`open_archive`, inflating every member (and
    counting), and return its member names.

    Raises
    ------
    FmuError
        As :func:`open_archive`, when a member inflates past its bound or is damaged, or when
        there is no ``modelDescription.xml``.
    """
    with open_archive(path, "FMU", budget, where) as archive:
        _require_model_description(archive)
        archive.check()
        return list(archive.members)


def _require_model_description(archive: CheckedArchive) -> None:
    if "modelDescription.xml" not in archive.members:
        raise FmuError(f"{archive.where}: not an FMU (no modelDescription.xml at the top "
                       "level)")


def safe_extract(path: Path, dest: Path, budget: Budget | None = None,
                 where: str | None = None) -> Path:
    """Check the FMU ``path`` and extract it into ``dest`` (a fresh folder the caller owns).

    On any refusal the members already written stay in ``dest``, which the caller removes.
    """
    with open_archive(path, "FMU", budget, where) as archive:
        _require_model_description(archive)
        dest.mkdir(parents=True, exist_ok=True)
        archive.extract(dest)
    return dest


def check_model_identifier(identifier: str, where: str, interface: str = "CoSimulation"
                           ) -> str:
    """``identifier``, a model description's ``modelIdentifier``, if it is a C identifier
    (FMI 2.0 and 3.0 say it is); else a one-line refusal.  fmpy and the masters join it onto
    ``binaries/<platform>/`` and load that library: ``/abs/evil`` or ``../../x/evil`` would load
    one from outside the extracted FMU, which no check of the archive saw.

    Raises
    ------
    FmuError
        Naming ``where`` (the FMU), the element and the value.
    """
    if len(identifier) > MAX_IDENTIFIER_CHARS or not _IDENTIFIER.fullmatch(identifier):
        raise _refuse(where, f"its {interface} modelIdentifier {_show(identifier)} is not a C "
                             f"identifier ([A-Za-z_][A-Za-z0-9_]*, at most "
                             f"{MAX_IDENTIFIER_CHARS} characters: it names the library to "
                             "load)")
    return identifier


def _check_interface(element: str, attrs: dict[str, str], where: str) -> None:
    """Check the ``modelIdentifier`` of an interface element of a model description."""
    if element in _INTERFACES and "modelIdentifier" in attrs:
        check_model_identifier(attrs["modelIdentifier"], where, element)


class _Refused(Exception):
    pass


class XmlGuard:
    """Checks an XML document as it streams by (constant memory): nested at most
    :data:`MAX_XML_DEPTH` deep, and without a document type declaration, so that no entity
    (internal, external or parameter) is ever expanded by whoever parses it next: FMI and SSP
    documents never need one.

    Raises
    ------
    FmuError
        From :meth:`feed` or :meth:`close`: one line naming ``where`` and what is wrong.
    """

    def __init__(self, where: str) -> None:
        self.where = where
        #: The root element's attributes, once it has streamed by (``fmiVersion``).
        self.root_attributes: dict[str, str] = {}
        self._depth = 0
        self._root = ""
        self._parser = expat.ParserCreate()
        self._parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
        self._parser.StartElementHandler = self._start
        self._parser.EndElementHandler = self._end
        self._parser.StartDoctypeDeclHandler = self._doctype

    def _start(self, _name: str, attrs: dict[str, str]) -> None:
        if self._depth == 0:
            self.root_attributes = dict(attrs)
            self._root = _name
        self._depth += 1
        if self._depth == 2 and self._root == "fmiModelDescription":
            _check_interface(_name, attrs, self.where)
        if self._depth > MAX_XML_DEPTH:
            raise _Refused(f"elements nested more than {MAX_XML_DEPTH} deep")

    def _end(self, _name: str) -> None:
        self._depth -= 1

    def _doctype(self, *_args: object) -> None:
        raise _Refused("a document type declaration (DTD, entities)")

    def _parse(self, data: bytes, final: bool) -> None:
        try:
            self._parser.Parse(data, final)
        except _Refused as exc:
            raise _refuse(self.where, f"the XML has {exc}") from None
        except expat.ExpatError as exc:
            raise FmuError(f"{self.where}: not XML: {exc}") from None

    def feed(self, data: bytes) -> None:
        self._parse(data, False)

    def close(self) -> None:
        self._parse(b"", True)


def parse_xml(data: bytes, where: str) -> ET.Element:
    """Parse an XML document from a stranger: at most :data:`MAX_XML_BYTES`, and passed by
    :class:`XmlGuard` first.

    Raises
    ------
    FmuError
        One line naming ``where`` and what is wrong.
    """
    if len(data) > MAX_XML_BYTES:
        raise _refuse(where, f"{len(data)} bytes of XML, more than {MAX_XML_BYTES}")
    guard = XmlGuard(where)
    guard.feed(data)
    guard.close()
    return ET.fromstring(data)


def file_sha256(path: Path, field: str | None = None) -> str:
    """The SHA-256 of an FMU file, read a chunk at a time (an archive may be large), and only
    a regular file of at most :data:`~wmr.infra.inputs.MAX_ARCHIVE_BYTES` (a FIFO or
    ``/dev/zero`` was hashed for ever); a refusal names ``field`` (default: the path)."""
    return sha256_input(path, field or str(path), max_bytes=MAX_ARCHIVE_BYTES, what="an FMU",
                        fix="give an FMU file")


__all__ = ["MAX_IDENTIFIER_CHARS", "MAX_MEMBERS", "MAX_MODEL_DESCRIPTION_BYTES",
           "MAX_UNCOMPRESSED_BYTES", "MAX_XML_BYTES", "MAX_XML_DEPTH", "Budget",
           "CheckedArchive", "XmlGuard", "check_archive", "check_model_identifier",
           "file_sha256", "open_archive", "parse_xml", "safe_extract"]
