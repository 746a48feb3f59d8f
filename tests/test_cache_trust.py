"""Nothing is loaded that was not checked (issue 28): a cache entry (the C stepper, the built
FMUs, pymoca's parser cache) is used only if this user owns it and no one else can write it or
a folder above it up to the cache's root; the stale-folder cleaner touches only folders of
ours.  Run as root: other users are made with ``os.chown``."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

#: A user id nobody on the test machine has: "another local user".
OTHER_UID = 54321

#: A library whose constructor writes a marker file: it says whether it was ever loaded.
MARKER_C = """#include <stdio.h>
__attribute__((constructor)) static void owned(void) {
    FILE *f = fopen("%s", "w");
    if (f) { fputs("owned", f); fclose(f); }
}
"""

needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="chown to another user needs root")


def _planted_library(path: Path, marker: Path) -> None:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    source = path.with_suffix(".c")
    source.write_text(MARKER_C % marker)
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(path), str(source)], check=True)
    source.unlink()


# ------------------------------------------------------------------ the stale-folder cleaner


@needs_root
def test_the_stale_folder_cleaner_follows_no_link_and_removes_only_our_folders(
        tmp_path: Path) -> None:
    """The cleaner opened ``wmr-fmu-*/.wmr-owner.lock`` read-write through any link, whoever
    owned the folder, then removed the folder: a planted link made root open and lock a
    root-only file.  Now: a link is not opened, another user's folder is left alone."""
    from wmr.adapters.fmi.slave import remove_stale_folders

    secret = tmp_path / "root-only.txt"
    secret.write_text("secret")
    secret.chmod(0o600)
    linked = tmp_path / "wmr-fmu-linked"
    linked.mkdir()
    (linked / ".wmr-owner.lock").symlink_to(secret)
    theirs = tmp_path / "wmr-fmu-theirs"
    theirs.mkdir()
    (theirs / ".wmr-owner.lock").write_text("")
    os.chown(theirs / ".wmr-owner.lock", OTHER_UID, OTHER_UID)
    os.chown(theirs, OTHER_UID, OTHER_UID)
    planted_file = tmp_path / "wmr-fmu-file"
    planted_file.mkdir()
    (planted_file / ".wmr-owner.lock").write_text("")
    os.chown(planted_file / ".wmr-owner.lock", OTHER_UID, OTHER_UID)
    dir_link = tmp_path / "wmr-fmu-dirlink"
    dir_link.symlink_to(theirs)
    ours = tmp_path / "wmr-fmu-ours"  # a killed run's folder: removed as before
    ours.mkdir()
    (ours / ".wmr-owner.lock").write_text("")

    assert remove_stale_folders(tmp_path) == [ours]
    assert linked.is_dir() and theirs.is_dir() and planted_file.is_dir() and dir_link.exists()
    assert secret.read_text() == "secret" and not ours.exists()
