"""Open an FMU archive safely: a hostile or broken archive is refused with a clear reason."""

from __future__ import annotations

import hashlib
import stat
import zipfile
from pathlib import Path, PurePosixPath

from wmr.infra.errors import FmuError

MAX_UNCOMPRESSED_BYTES = 512 * 1024 * 1024
MAX_MEMBERS = 10_000


def check_archive(path: Path) -> list[str]:
    """Return the member names of the FMU at ``path`` after checking that it is safe to extract.

    Raises
    ------
    FmuError
        When the file is missing, not a zip archive, has members that would land outside the
        extraction folder (absolute paths, ``..``, links), is a zip bomb, or has no
        ``modelDescription.xml``.
    """
    if not path.is_file():
        raise FmuError(f"{path}: no such FMU file (build one with 'wmr fmu build')")
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
    except (zipfile.BadZipFile, OSError) as exc:
        raise FmuError(f"{path}: not an FMU (not a zip archive: {exc})") from exc
    if len(infos) > MAX_MEMBERS:
        raise FmuError(f"{path}: {len(infos)} members, more than {MAX_MEMBERS}: refused")
    total = 0
    names = []
    for info in infos:
        name = info.filename
        pure = PurePosixPath(name.replace("\\", "/"))
        if pure.is_absolute() or ".." in pure.parts or (pure.parts and ":" in pure.parts[0]):
            raise FmuError(f"{path}: member {name!r} would be written outside the FMU folder")
        if stat.S_ISLNK(info.external_attr >> 16):
            raise FmuError(f"{path}: member {name!r} is a symbolic link: refused")
        total += info.file_size
        if total > MAX_UNCOMPRESSED_BYTES:
            raise FmuError(f"{path}: unpacks to more than {MAX_UNCOMPRESSED_BYTES} bytes: refused")
        names.append(name)
    if "modelDescription.xml" not in names:
        raise FmuError(f"{path}: not an FMU (no modelDescription.xml at the top level)")
    return names


def safe_extract(path: Path, dest: Path) -> Path:
    """Extract the checked archive ``path`` into ``dest`` and return ``dest``."""
    check_archive(path)
    dest.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path) as zf:
        zf.extractall(dest)
    return dest


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()
