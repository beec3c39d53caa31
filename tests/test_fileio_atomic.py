"""cell/fileio.py: the atomic write (temp file, fsync, rename, directory fsync), what a failure
half-way leaves behind, the modes of the written file, the appenders' lock, the size cap and the
refusal of files that are not regular files. The file I/O is real (tmp_path); only os.fsync and
os.replace, the system boundary, are wrapped to watch the order or to make them fail."""

import errno
import os
import re
import stat
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from conftest import ROOT, run_cli

from calibration import default_calibration_path
from cell import fileio
from cell.errors import BadInput
from cell.fileio import append_lines_atomic, read_json, replace_lines_atomic, write_atomic

OLD = b'{"old": true}\n'
NEW = b'{"new": true}\n'


def _names(directory: Path) -> list[str]:
    """What is in the directory (the appenders' lock files included: none is left behind)."""
    return sorted(p.name for p in directory.iterdir())


def _fd_path(fd: int) -> str:
    return os.readlink(f"/proc/self/fd/{fd}")


def test_write_goes_to_a_fsynced_temp_file_renamed_over_the_target(tmp_path, monkeypatch):
    target = tmp_path / "a.json"
    target.write_bytes(OLD)
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        where = Path(_fd_path(fd))
        content = where.read_bytes() if where.is_file() else None
        events.append(("fsync", where, content, target.read_bytes()))
        real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", Path(src), Path(dst), Path(src).read_bytes()))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    write_atomic(target, NEW)

    assert [e[0] for e in events] == ["fsync", "replace", "fsync"]
    (_, synced, synced_content, target_then), (_, src, dst, renamed), (_, synced_dir, _, _) = events
    # the new bytes are on disk, in a temp file beside the target, before the target changes
    assert synced.parent == tmp_path and synced.name.startswith(".a.json.") and synced.name.endswith(".tmp")
    assert synced_content == NEW and target_then == OLD
    assert (src, dst, renamed) == (synced, target, NEW)
    assert synced_dir == tmp_path  # the rename itself is made durable
    assert target.read_bytes() == NEW and _names(tmp_path) == ["a.json"]


@pytest.mark.parametrize("step", ["fsync", "replace"])
@pytest.mark.parametrize("error", [OSError(errno.ENOSPC, "No space left on device"), KeyboardInterrupt()],
                         ids=["disk-full", "ctrl-c"])
@pytest.mark.parametrize("existed", [True, False], ids=["over-old-file", "new-file"])
def test_a_failure_while_writing_leaves_the_old_file_and_no_temp_file(tmp_path, monkeypatch, step, error,
                                                                      existed):
    target = tmp_path / "a.json"
    if existed:
        target.write_bytes(OLD)

    def fail(*args):
        raise error

    monkeypatch.setattr(os, step, fail)
    with pytest.raises(type(error)) as raised:
        write_atomic(target, NEW)
    monkeypatch.undo()
    if isinstance(error, OSError):  # the file asked for is named (a full disk said only "No space left on device")
        assert raised.value.filename == str(target) and raised.value.errno == errno.ENOSPC
    assert _names(tmp_path) == (["a.json"] if existed else [])
    if existed:
        assert target.read_bytes() == OLD


def test_a_rename_refused_by_the_file_system_leaves_no_temp_file(tmp_path):
    # no injection: the target is a non-empty directory, which rename(2) will not replace
    target = tmp_path / "a.json"
    target.mkdir()
    (target / "inside").write_bytes(OLD)
    with pytest.raises(OSError) as raised:
        write_atomic(target, NEW)
    assert _names(tmp_path) == ["a.json"] and (target / "inside").read_bytes() == OLD
    assert raised.value.filename == str(target)  # not the temp file, taken away by then


@pytest.mark.parametrize("old_mode, umask, expected", [
    (None, 0o022, 0o644),   # a new file: what open() makes, the usual 0644, not mkstemp's 0600 ...
    (None, 0o077, 0o600),   # ... under the umask (it was 0644 whatever the umask: a private user's files shared)
    (None, 0o002, 0o664),
    (0o600, 0o022, 0o600),  # an existing file keeps its mode: a private file stays private
    (0o640, 0o022, 0o640),
    (0o755, 0o077, 0o755),
], ids=["new", "new-umask-077", "new-umask-002", "keeps-0600", "keeps-0640", "keeps-0755"])
def test_the_written_file_has_the_old_files_mode_or_open_s(tmp_path, old_mode, umask, expected):
    target = tmp_path / "a.json"
    if old_mode is not None:
        target.write_bytes(OLD)
        target.chmod(old_mode)
    previous = os.umask(umask)
    try:
        write_atomic(target, NEW)
    finally:
        os.umask(previous)
    assert stat.S_IMODE(target.stat().st_mode) == expected and target.read_bytes() == NEW


class _Interleave:
    """Runs an append whose check holds the lock while another writer tries to get in."""

    def __init__(self, path: Path):
        self.path, self.inside, self.errors = path, threading.Event(), []

    def slow_check(self, old: bytes):
        self.inside.set()
        threading.Event().wait(0.3)  # the other writer starts meanwhile

    def run(self, other):
        def first():
            try:
                append_lines_atomic(self.path, ["a"], check=self.slow_check)
            except Exception as e:  # pragma: no cover - reported below
                self.errors.append(e)

        t1 = threading.Thread(target=first)
        t1.start()
        assert self.inside.wait(5)
        t2 = threading.Thread(target=other)
        t2.start()
        t1.join(10)
        t2.join(10)
        assert not self.errors


@pytest.mark.parametrize("other, expected", [
    (lambda p: append_lines_atomic(p, ["b"]), "x\na\nb\n"),  # no line of either appender lost
    (lambda p: replace_lines_atomic(p, ["new"]), "new\n"),   # the replacement not undone by the append
], ids=["append", "replace"])
def test_writers_of_a_line_file_wait_for_each_other(tmp_path, other, expected):
    path = tmp_path / "lines.jsonl"
    path.write_text("x\n")
    _Interleave(path).run(lambda: other(path))
    assert path.read_text() == expected and _names(tmp_path) == ["lines.jsonl"]


def test_a_writer_that_waited_on_a_removed_lock_file_takes_the_lock_again(tmp_path):
    """The holder removes the lock file before letting go. B, waiting on that file meanwhile, then holds a
    lock on a file no name leads to, and C, coming after the removal, makes a new one: both would be in
    at once (and one's line lost), unless B sees the name no longer leads to its file and locks again."""
    path = tmp_path / "lines.jsonl"
    path.write_text("x\n")
    a_inside, release_a = threading.Event(), threading.Event()
    inside, overlaps, errors = [], [], []

    def held(old: bytes):  # B's and C's check: a while inside the lock, noting who else is
        if inside:
            overlaps.append(list(inside))
        inside.append(threading.current_thread().name)
        threading.Event().wait(0.4)
        inside.pop()

    def writer(line, check):
        try:
            append_lines_atomic(path, [line], check=check)
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)

    a = threading.Thread(target=writer, args=("a", lambda old: (a_inside.set(), release_a.wait(5))))
    b = threading.Thread(target=writer, args=("b", held), name="b")
    a.start()
    assert a_inside.wait(5)
    b.start()
    threading.Event().wait(0.3)  # b has opened the lock file and waits for it
    release_a.set()
    a.join(5)  # a removed the lock file and let go: b takes it ...
    c = threading.Thread(target=writer, args=("c", held), name="c")
    c.start()  # ... and c comes while b is inside
    b.join(10)
    c.join(10)
    assert not errors and not overlaps
    assert sorted(path.read_text().split()) == ["a", "b", "c", "x"] and _names(tmp_path) == ["lines.jsonl"]


def test_examples_generate_leaves_no_lock_file_beside_its_output(tmp_path, capsys):
    code, out, err = run_cli("examples", "generate", "--out", tmp_path / "ex.jsonl", "--count", "1", capsys=capsys)
    assert code == 0 and _names(tmp_path) == ["ex.jsonl"]  # was also .ex.jsonl.lock
    code, out, err = run_cli("examples", "generate", "--out", tmp_path / "ex.jsonl", "--count", "1", "--seed", "1",
                             "--append", capsys=capsys)
    assert code == 0 and _names(tmp_path) == ["ex.jsonl"]


def test_an_append_its_check_refuses_leaves_the_file_byte_for_byte(tmp_path):
    path = tmp_path / "lines.jsonl"
    path.write_bytes(b"one\ntwo")  # no final newline: an append would add one
    before = path.stat()

    def refuse(old: bytes):
        assert old == b"one\ntwo"  # the check sees the file as it is under the lock
        raise BadInput("no")

    with pytest.raises(BadInput, match="no"):
        append_lines_atomic(path, ["three"], check=refuse)
    assert path.read_bytes() == b"one\ntwo" and _names(tmp_path) == ["lines.jsonl"]
    assert path.stat().st_ino == before.st_ino  # not even rewritten with the same bytes


# --- the size cap -------------------------------------------------------------------------------


def _sparse(path: Path, size: int) -> Path:
    with open(path, "wb") as f:
        f.truncate(size)  # no data blocks: instant, and never read (the cap is checked first)
    return path


def test_the_size_cap_is_256_mb_and_refuses_one_byte_more_before_reading(tmp_path):
    assert fileio.MAX_JSON_BYTES == 256 * 2**20
    path = _sparse(tmp_path / "big.json", fileio.MAX_JSON_BYTES + 1)
    with pytest.raises(BadInput, match=r"scene file .*big.json is 256 MB: more than the 256 MB a scene file may have"):
        read_json(path, "scene file")


@pytest.mark.parametrize("extra, ok", [(-1, True), (0, True), (1, False)], ids=["cap-1", "cap", "cap+1"])
def test_the_size_cap_boundary(tmp_path, monkeypatch, extra, ok):
    # the cap made small so that a file of exactly the cap is cheap to write and read
    monkeypatch.setattr(fileio, "MAX_JSON_BYTES", 64)
    path = tmp_path / "a.json"
    path.write_bytes(b'{"k": 1}' + b" " * (64 - 8 + extra))
    assert path.stat().st_size == 64 + extra
    if ok:
        assert read_json(path, "cell file") == {"k": 1}
    else:
        with pytest.raises(BadInput, match="more than the"):
            read_json(path, "cell file")


def test_an_oversized_calibration_through_the_cli_is_exit_2(tmp_path, capsys):
    path = _sparse(tmp_path / "cal.json", fileio.MAX_JSON_BYTES + 1)
    code, out, err = run_cli("map", path, "--px", "1,2", capsys=capsys)
    assert code == 2 and out == "" and "more than the 256 MB" in err and "Traceback" not in err


# --- files that are not regular files -------------------------------------------------------------


@pytest.fixture
def fifo(tmp_path):
    """A FIFO nobody writes to. Reading it would block for ever; should the check that refuses it
    go, a helper opens it for writing once a reader waits and closes it again, so that the read
    ends (the test then fails on the message instead of hanging)."""
    path = tmp_path / "in.fifo"
    os.mkfifo(path)
    stop = threading.Event()

    def unblock():
        while not stop.wait(0.05):
            try:
                fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
            except OSError:  # ENXIO: nobody is reading
                continue
            os.close(fd)

    t = threading.Thread(target=unblock, daemon=True)
    t.start()
    yield path
    stop.set()
    t.join(5)


def _make(kind: str, tmp_path: Path, fifo: Path) -> Path:
    if kind == "directory":
        (tmp_path / "d.json").mkdir()
        return tmp_path / "d.json"
    if kind == "fifo":
        return fifo
    if kind == "dev-null":
        return Path("/dev/null")
    if kind == "link-to-dev-null":
        (tmp_path / "l.json").symlink_to("/dev/null")
        return tmp_path / "l.json"
    if kind == "link-to-directory":
        (tmp_path / "l.json").symlink_to(tmp_path)
        return tmp_path / "l.json"
    if kind == "dangling-link":
        (tmp_path / "l.json").symlink_to(tmp_path / "gone.json")
        return tmp_path / "l.json"
    raise AssertionError(kind)


NOT_REGULAR = [
    ("directory", "is a directory, not a file"),
    ("fifo", "is not a regular file"),
    ("dev-null", "is not a regular file"),  # a character device, as /dev/zero (below, in a subprocess)
    ("link-to-dev-null", "is not a regular file"),
    ("link-to-directory", "is a directory, not a file"),
    ("dangling-link", "does not exist"),
]


@pytest.mark.parametrize("kind, message", NOT_REGULAR, ids=[k for k, _ in NOT_REGULAR])
def test_reading_what_is_not_a_regular_file_is_refused(tmp_path, fifo, kind, message):
    path = _make(kind, tmp_path, fifo)
    with pytest.raises(BadInput, match=f"^{re.escape(f'cell file {path} {message}')}$"):
        read_json(path, "cell file")


@pytest.mark.parametrize("kind, message", NOT_REGULAR[:3], ids=[k for k, _ in NOT_REGULAR[:3]])
def test_a_calibration_that_is_not_a_regular_file_is_exit_2(tmp_path, fifo, capsys, kind, message):
    path = _make(kind, tmp_path, fifo)
    code, out, err = run_cli("map", path, "--px", "1,2", capsys=capsys)
    assert code == 2 and out == "" and message in err and "Traceback" not in err


def test_a_link_to_a_regular_file_is_read(tmp_path):
    (tmp_path / "l.json").symlink_to(default_calibration_path())
    assert read_json(tmp_path / "l.json", "calibration file")["version"] == 1


def test_dev_zero_is_refused_without_reading_it():
    # in a child with 512 MB of address space: were it read, it would fill the memory (MemoryError)
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (512 * 2**20,) * 2)\n"
            "from cell.errors import BadInput\nfrom cell.fileio import read_json\n"
            "try:\n    read_json('/dev/zero', 'scene file')\nexcept BadInput as e:\n    print(e)\n")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "scene file /dev/zero is not a regular file\n"
