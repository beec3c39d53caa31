"""Files are written atomically (temp file + fsync + rename) and read with clear errors.

Every user-facing file (cell files, example files, calibrations, recordings) goes through
here so that a crash never leaves half a file and a bad file names itself in the error.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import re
import stat
import tempfile
from pathlib import Path

import numpy as np

from cell.errors import BadInput


def write_atomic(path: str | os.PathLike, data: str | bytes) -> None:
    """Replace `path` with `data` so that readers see the old or the new file, never a mix."""
    path = _through_link(Path(path))
    _refuse_to_replace_a_special_file(path, "cannot write")
    refuse_read_only(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as e:  # name the file asked for, not the temp file that could not be made
        raise OSError(e.errno, e.strerror, str(path)) from None
    try:
        # mkstemp makes 0600 files; keep an existing file's mode, else what open() would make (0666 less the
        # umask: 0644 usually; a user's 077 keeps them private, a group's 002 shares them)
        os.fchmod(fd, path.stat().st_mode & 0o777 if path.exists() else 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            f.write(raw)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(e, OSError) and e.filename in (None, tmp):  # a full disk said only the error; a failed
            raise OSError(e.errno, e.strerror, str(path)) from None  # rename named the temp file, gone by now
        raise
    _fsync_dir(path.parent)


def _umask() -> int:
    """The process's umask, read without setting it (os.umask sets it: another thread's file made meanwhile
    would get the wrong mode); where /proc does not say, set and put back."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _through_link(path: Path) -> Path:
    """The file a symbolic link leads to (dangling: the one it names): the rename would put a plain file in the
    link's place, and the file it leads to (a calibration kept by date, `current.json` naming the one in use)
    would keep its old content."""
    return Path(os.path.realpath(path)) if path.is_symlink() else path


def _refuse_to_replace_a_special_file(path: Path, what: str) -> None:
    """The temp file is renamed over `path`: over a FIFO or a device (--out /dev/null, run as root) that
    would put a plain file in its place. (A directory the rename refuses by itself.)"""
    try:
        st = path.stat()
    except OSError:
        return  # missing (the usual case) or unreachable: the write itself says what is wrong
    if not stat.S_ISREG(st.st_mode) and not stat.S_ISDIR(st.st_mode):
        raise BadInput(f"{what} {path}: it is not a regular file (a pipe or a device); it is written by renaming "
                       "a new file over it, which would replace it")


def _not_writable(path: Path, mode: int = os.W_OK) -> bool:
    """No write permission for us, or none for anyone: root's access() allows every write, but a user who
    took the write bits away means "leave it as it is", whoever runs the command."""
    return not os.stat(path).st_mode & 0o222 or not os.access(path, mode)


def _refuse_read_only_file(path: Path, name: str) -> None:
    if path.is_file() and _not_writable(path):
        raise BadInput(f"{name} is read-only: not replaced")


def refuse_read_only(path: Path) -> None:
    """The temp file is renamed over `path`, which only the folder's permissions stop: a read-only file was
    replaced without a word. Refused, as is a read-only folder (which root could write into)."""
    _refuse_read_only_file(path, str(path))
    if path.parent.is_dir() and _not_writable(path.parent, os.W_OK | os.X_OK):  # the temp file is made there
        raise BadInput(f"{path}: the folder {path.parent} is not writable")


def check_writable(path: str | os.PathLike, what: str) -> None:
    """Refuse, before any work is done, an output path that cannot become a file: a directory, a FIFO or
    a device, a read-only file or folder, or a path under a file (`write_atomic` would fail only after the
    work, naming its temp file)."""
    path = _through_link(Path(path))
    if path.is_dir():
        raise BadInput(f"{what} {path} is a directory, not a file")
    _refuse_to_replace_a_special_file(path, what)
    _refuse_read_only_file(path, f"{what} {path}")
    check_folder_writable(path.parent, f"{what} {path}")  # (the folder: once, here)


def check_folder_writable(folder: Path, what: str) -> None:
    """The nearest of `folder` and its parents that exists must be a writable folder (the others are made in it).
    `what` starts the message."""
    for parent in (folder, *folder.parents):
        if parent.exists():
            if not parent.is_dir():
                raise BadInput(f"{what}: {parent} is a file, not a folder")
            # (a read-only mount would fail only at the write)
            if _not_writable(parent, os.W_OK | os.X_OK) or os.statvfs(parent).f_flag & os.ST_RDONLY:
                raise BadInput(f"{what}: the folder {parent} is not writable")
            return


def make_folder(folder: Path, what: str) -> None:
    """Make an output folder and its missing parents before any work: refused (BadInput, `what` first) where
    it cannot be one, a file or a read-only place (checked before making it: root could make it in a
    read-only folder)."""
    check_folder_writable(folder, what)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise BadInput(f"{what}: cannot make the folder {folder}: {e.strerror or e}") from None


def file_sha256(path: str | os.PathLike) -> str:
    """The file's sha256 (hex), read a MB at a time."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_json_atomic(path: str | os.PathLike, obj) -> None:
    write_atomic(path, json.dumps(obj, indent=2) + "\n")


@contextlib.contextmanager
def _file_lock(path: Path):
    """The lock every writer of a line file takes (appenders and replacers alike): flock on `.NAME.lock`
    beside it, a file its holder removes before letting go (it was left next to every output). Removing
    it is safe because a writer that waited on the removed file sees that the name no longer leads to
    it and takes the lock again, on the file the name now leads to: else it and a writer that came after
    the removal (and made a new file) would both hold "the" lock."""
    path = _through_link(path)  # (the lock beside the file written, not beside the link)
    refuse_read_only(path)  # before the lock file is made
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = path.with_name(f".{path.name}.lock")
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            with contextlib.suppress(FileNotFoundError):
                if os.path.samestat(os.fstat(fd), os.stat(lock)):
                    break
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)  # its holder removed it while we waited
    try:
        yield
    finally:
        with contextlib.suppress(OSError):  # (one left behind, say in a folder made read-only meanwhile, is harmless)
            os.unlink(lock)  # while still holding it
        os.close(fd)


def replace_lines_atomic(path: str | os.PathLike, lines: list[str]) -> None:
    """Replace a line file atomically, under the appenders' lock: an append in progress (which
    read the old file) would otherwise write the old lines back over the new file."""
    path = Path(path)
    with _file_lock(path):
        write_atomic(path, "".join(line.rstrip("\n") + "\n" for line in lines))


def append_lines_atomic(path: str | os.PathLike, lines: list[str], check=None) -> None:
    """Append whole lines: the file is rewritten to a temp file and renamed, under a lock,
    so a crash or a concurrent appender never leaves a torn last line. `check(old_bytes)`,
    if given, runs under the lock on the file as it is then and may refuse the append by
    raising (a check made before taking the lock could miss a concurrent appender's lines)."""
    path = Path(path)
    with _file_lock(path):
        check_readable(path, "line file")  # a FIFO would block the read, then be replaced by a file
        old = path.read_bytes() if path.exists() else b""
        if check is not None:
            check(old)
        if old and not old.endswith(b"\n"):
            old += b"\n"
        new = "".join(line.rstrip("\n") + "\n" for line in lines).encode("utf-8")
        write_atomic(path, old + new)


class DuplicateKey(ValueError):
    """A JSON object names a key twice: json keeps the last silently (a cell file with two
    `j1_deg` would run with whichever came last)."""


def unique_keys(pairs: list) -> dict:
    """`object_pairs_hook` for json.loads: the object as a dict, refusing a key given twice."""
    out = {}
    for k, v in pairs:
        if k in out:
            raise DuplicateKey(f"key {k!r} appears twice in one object")
        out[k] = v
    return out


MAX_JSON_INT_DIGITS = 4300  # what int() converts by default (sys.get_int_max_str_digits): no cell value comes close


class _NumberTooLarge(ValueError):
    pass


def _parse_json_int(s: str) -> int:
    if len(s) - s.startswith("-") > MAX_JSON_INT_DIGITS:
        raise _NumberTooLarge(s)
    return int(s)


def json_loads(text: str, **kw):
    """json.loads for every file the project reads: a key given twice in one object is a DuplicateKey
    (which the callers report naming the file, and the line of a JSON Lines file); an integer of more than
    MAX_JSON_INT_DIGITS digits is a JSONDecodeError ("a number too large", at the number's line and column)
    that the callers report as any other invalid JSON; json.loads itself raises a plain ValueError (int()'s
    digit limit) there."""
    try:
        return json.loads(text, parse_int=_parse_json_int, object_pairs_hook=unique_keys, **kw)
    except _NumberTooLarge as e:
        digits = str(e.args[0])
        pos = 0
        for m in re.finditer(re.escape(digits), text):  # the number's place (not digits inside a string)
            before = text[m.start() - 1] if m.start() else " "
            after = text[m.end()] if m.end() < len(text) else " "
            if before in "[,: \t\r\n" and after in "]}, \t\r\n":
                pos = m.start()
                break
        n = len(digits) - digits.startswith("-")
        raise json.JSONDecodeError(f"a number too large: {n} digits, at most {MAX_JSON_INT_DIGITS}",
                                   text, pos) from None


MAX_JSON_BYTES = 256 * 2**20  # a scene of 200 parts drawn every 0.02 mm is 12 MB


def check_readable(path: Path, what: str, max_bytes: float | None = None) -> None:
    """Refuse what must not be read whole: anything but a regular file (a FIFO would block,
    /dev/zero would fill the memory) and files over max_bytes (None: MAX_JSON_BYTES as it is
    then; math.inf: any size). A missing file passes (the caller says what that means); `what`
    names the file's role in the message."""
    if max_bytes is None:
        max_bytes = MAX_JSON_BYTES
    try:
        st = path.stat()
    except FileNotFoundError:
        return
    except OSError as e:
        raise BadInput(f"{what} {path} cannot be read: {e}") from None
    if stat.S_ISDIR(st.st_mode):
        raise BadInput(f"{what} {path} is a directory, not a file")
    if not stat.S_ISREG(st.st_mode):
        raise BadInput(f"{what} {path} is not a regular file")
    if st.st_size > max_bytes:
        raise BadInput(f"{what} {path} is {st.st_size / 2**20:.0f} MB: more than the "
                       f"{max_bytes / 2**20:.0f} MB a {what} may have")


def read_text(path: str | os.PathLike, what: str) -> str:
    """A file's text (`check_readable` first), with the error naming the file by its role."""
    path = Path(path)
    check_readable(path, what)
    try:
        return path.read_text(encoding="utf-8-sig")  # a BOM (Windows editors write one) is not content
    except FileNotFoundError:
        raise BadInput(f"{what} {path} does not exist") from None
    except IsADirectoryError:
        raise BadInput(f"{what} {path} is a directory, not a file") from None
    except (OSError, UnicodeDecodeError) as e:
        raise BadInput(f"{what} {path} cannot be read: {e}") from None


def read_json(path: str | os.PathLike, what: str):
    """Parse a JSON file (`read_text`); `what` names the file's role in error messages ("cell file")."""
    path = Path(path)
    return parse_json(read_text(path, what), f"{what} {path}")


def parse_json(text: str, where: str):
    """`json_loads` of a text every problem of which is a BadInput starting with `where` (a file, a request
    body): invalid JSON (with its line and column), a key given twice, nesting too deep, a lone surrogate."""
    try:
        obj = json_loads(text)
    except json.JSONDecodeError as e:
        raise BadInput(f"{where} is not valid JSON: {e.msg} at line {e.lineno} column {e.colno}") from None
    except DuplicateKey as e:
        raise BadInput(f"{where}: {e}") from None
    except RecursionError:  # json's decoder recurses per nesting level: [[[[...]]]] 100000 deep
        raise BadInput(f"{where} is not valid JSON: nested too deeply") from None
    refuse_lone_surrogates(text, obj, where)
    return obj


_SURROGATE_ESCAPE = re.compile(r"\\[uU][dD][89a-fA-F][0-9a-fA-F]{2}")


def refuse_lone_surrogates(text: str, obj, where: str) -> None:
    """JSON's `\\udc80` escape gives a string no UTF-8 text holds (half of a UTF-16 pair): as a part id it ended
    `cell plan --figures` in an internal error (the font cannot draw it). Only a text that has such an escape
    is walked (a pair, `\\ud83d\\ude00`, is one character after parsing, and passes)."""
    if not _SURROGATE_ESCAPE.search(text):
        return

    def walk(v, at: str):
        if isinstance(v, str):
            try:
                v.encode("utf-8")
            except UnicodeEncodeError:
                raise BadInput(f"{where}: {at or 'the value'} holds a lone UTF-16 surrogate escape "
                               f"({ascii(v)[1:-1][:60]}): no character") from None
        elif isinstance(v, dict):
            for k, x in v.items():
                walk(k, at)
                walk(x, f"{at}.{k}" if at else str(k))
        elif isinstance(v, list):
            for i, x in enumerate(v):
                walk(x, f"{at}[{i}]")

    try:
        walk(obj, "")
    except RecursionError:
        raise BadInput(f"{where} is not valid JSON: nested too deeply") from None


def _fsync_dir(directory: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def json_text(text: str) -> str:
    """`text` as a JSON file may hold it: a name with bytes that are not UTF-8 (Python keeps each as a lone
    surrogate, which our readers refuse) with those bytes written as \\xNN (`cell run --record $'r\\xff'` made a
    recording that its replay refused)."""
    if text.isascii() or not any("\ud800" <= ch <= "\udfff" for ch in text):
        return text
    try:
        return os.fsencode(text).decode("utf-8", "backslashreplace")  # the name's own bytes, \xNN where not UTF-8
    except UnicodeEncodeError:  # a surrogate that came from no name
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def to_jsonable(obj, *, nonfinite: str = "error"):
    """numpy arrays and scalars, tuples, Paths and objects with `as_dict`/`to_json` -> plain JSON.

    A non-finite float raises ValueError (JSON cannot store it), or becomes null with
    `nonfinite="null"`."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v, nonfinite=nonfinite) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v, nonfinite=nonfinite) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist(), nonfinite=nonfinite)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        if not math.isfinite(f):
            if nonfinite == "null":
                return None
            raise ValueError(f"a non-finite number ({f}): JSON cannot store it")
        return f
    if isinstance(obj, (str, Path)):
        return json_text(str(obj))
    for method in ("to_json", "as_dict"):
        if hasattr(obj, method):
            return to_jsonable(getattr(obj, method)(), nonfinite=nonfinite)
    if obj is None or isinstance(obj, (str, int, bool)):
        return obj
    raise TypeError(f"a {type(obj).__name__} cannot be written as JSON")


def is_finite_number(v) -> bool:
    """Is this JSON value a finite number? true/false are not numbers, and an integer literal too large for
    a float (JSON allows any length: 10**400) overflows math.isfinite."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def as_written(v) -> str:
    """A value as a message quotes it in full: values read from JSON spelt as the file spells them (null,
    true, [1, "a"]), not as Python does (None, True); a string alone keeps its quotes."""
    if isinstance(v, str):
        return repr(v)
    try:
        return json.dumps(v)
    except (TypeError, ValueError):  # not a JSON value (a numpy array, a path): as Python shows it
        return repr(v)


def short_repr(v) -> str:
    """A value as an error message quotes it (`as_written`): at most 40 characters."""
    r = as_written(v)
    return r if len(r) <= 40 else r[:37] + "..."


def short_text(text: str) -> str:
    """A name or an option's text as an error message shows it: as given when short and printable, else
    short_repr's 40 characters."""
    return text if len(text) <= 40 and text.isprintable() else short_repr(text)


def has_non_number(v) -> bool:
    """Is there a true/false or a string anywhere in this JSON value's nested lists? (numpy reads True
    as 1 and "100" as 100: a matrix or a point given as [true, 0] or ["100", 0] must be refused, not
    read as numbers.)"""
    return isinstance(v, (bool, str)) or (isinstance(v, list) and any(has_non_number(x) for x in v))
