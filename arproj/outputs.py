"""Result folders written whole (a map, a rig): everything goes into a sibling temporary folder, which then
takes the old folder's place in one rename, so a kill at any moment leaves either the old complete folder or the
new one, never a mix or a truncated file; a refusal or a failure before that leaves the old one as it was.

    with OutputFolder(out, MAP_FILES, "map folder") as tmp:   # checked before any work: see check()
        ...write every file into tmp...
    # here out holds exactly what was written into tmp

The swap is Linux's renameat2(RENAME_EXCHANGE) where the file system has it; elsewhere two renames, and a kill
between them leaves the old folder as `.NAME.old-PID`, which the next OutputFolder on that path puts back.
Leftovers of killed writers (`.NAME.new-PID`, `.NAME.old-PID` of processes that are gone) are removed then too.
A folder that holds anything this writer does not write is refused rather than replaced, so that no file of a
person's is ever swapped away.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import shutil
from collections.abc import Collection
from pathlib import Path
from types import TracebackType

from geometry.errors import InputError

_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


class OutputFolder:
    """Write `target` whole. owned: the names a folder written by this command may hold (anything else in an
    existing target refuses it); keep: owned names carried over from the old folder when the new one lacks them
    (files another step put there, e.g. the demo's range images in a map folder); what names it in messages."""

    def __init__(self, target: str | Path, owned: Collection[str], what: str, option: str = "--out",
                 keep: Collection[str] = ()) -> None:
        self.target = Path(target)
        self.owned = frozenset(owned)
        self.keep = frozenset(keep)
        self.what = what
        self.option = option
        self._tmp: Path | None = None

    def _sibling(self, kind: str, pid: int | None = None) -> Path:
        return self.target.with_name(f".{self.target.name}.{kind}-{os.getpid() if pid is None else pid}")

    def check(self) -> None:
        """Raise InputError unless target may be replaced (absent, or a folder holding only owned names);
        put back an old folder a killed writer left aside and remove killed writers' leftovers."""
        self._recover()
        if self.target.is_symlink() or (self.target.exists() and not self.target.is_dir()):
            raise InputError(f"{self.option} {self.target}: not a folder", f"give a folder for the {self.what}")
        if self.target.is_dir():
            foreign = sorted(p.name for p in self.target.iterdir() if p.name not in self.owned or p.is_dir())
            if foreign:
                shown = ", ".join(foreign[:5]) + (", …" if len(foreign) > 5 else "")
                raise InputError(f"{self.option} {self.target}: holds what a {self.what} does not ({shown}); it "
                                 "is replaced as a whole, so nothing else may be in it",
                                 f"give a new folder, or one that holds only a {self.what}")

    def _recover(self) -> None:
        parent = self.target.parent
        if not parent.is_dir():
            return
        for kind in ("old", "new"):
            for leftover in parent.glob(f".{self.target.name}.{kind}-*"):
                pid = leftover.name.rsplit("-", 1)[-1]
                if not pid.isdigit() or _alive(int(pid)):
                    continue
                if kind == "old" and not self.target.exists():
                    os.rename(leftover, self.target)  # killed between the two renames: the old folder returns
                else:
                    shutil.rmtree(leftover, ignore_errors=True)

    def __enter__(self) -> Path:
        self.check()
        self.target.parent.mkdir(parents=True, exist_ok=True)
        self._tmp = self._sibling("new")
        shutil.rmtree(self._tmp, ignore_errors=True)
        self._tmp.mkdir()
        return self._tmp

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        assert self._tmp is not None
        tmp, self._tmp = self._tmp, None
        if exc_type is not None:
            shutil.rmtree(tmp, ignore_errors=True)
            return
        self._commit(tmp)

    def _commit(self, tmp: Path) -> None:
        if self.target.is_dir():
            for name in self.keep:
                old = self.target / name
                if old.is_file() and not (tmp / name).exists():
                    _link_or_copy(old, tmp / name)
        _fsync_tree(tmp)
        if not self.target.exists():
            os.rename(tmp, self.target)
        elif _exchange(tmp, self.target):
            shutil.rmtree(tmp)  # tmp now holds the old folder
        else:
            aside = self._sibling("old")
            os.rename(self.target, aside)
            os.rename(tmp, self.target)
            shutil.rmtree(aside)
        _fsync_dir(self.target.parent)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (renameat2 RENAME_EXCHANGE); False where the system cannot."""
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(code, f"cannot swap {a} and {b}: {os.strerror(code)}")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _link_or_copy(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _fsync_tree(folder: Path) -> None:
    """Flush every file and the folder itself, so that the swap never makes visible a file still in cache."""
    for path in folder.iterdir():
        if path.is_file():
            with open(path, "rb") as handle:
                os.fsync(handle.fileno())
    _fsync_dir(folder)


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
