"""The results store of ``olado bench``: a JSON Lines file, one record per line, appended one
solve at a time (docs/benchmarking.md, "Store" and "Resume").

Why JSON Lines and not SQLite: a benchmark writes from one process (the runner; workers only
answer it), appends and never updates, and its records are read whole (profiles, tables,
comparisons). A text file appended line by line does that with the standard library, can be read
by anything (``jq``, pandas, a text editor), diffed and concatenated, and its failure mode under
``kill -9`` or power loss is simple: at most the last line is incomplete.

* **Append.** A record is one line, written with a single ``os.write`` on a descriptor opened with
  ``O_APPEND`` and then ``fsync``-ed: a killed run leaves every earlier record complete.
* **Repair.** Opening a store for writing drops an incomplete last line (no newline at the end:
  a write cut short); that solve is simply run again. An unreadable line elsewhere is not a
  write cut short but a damaged file: a :class:`~olado.errors.ResultFileError` naming the line.
* **One writer.** The writer holds an exclusive ``flock`` on the file; a second ``olado bench``
  on the same store stops with an error instead of interleaving records.
* **Keys.** A record's key is (problem, N, start, config_hash) (:data:`~olado.bench.records.KEY_FIELDS`);
  the runner skips the keys already present, so a resumed run neither repeats nor loses a solve.
  Should a file hold a key twice (two stores concatenated), readers keep the last record.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from ..errors import ConfigError, ResultFileError
from .records import record_key


def _parse(lines, path, start_line=1) -> list[dict]:
    records = []
    for i, line in enumerate(lines, start_line):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            raise ResultFileError(f"{path}: line {i} is not a JSON record ({exc.msg}); the store is damaged") from None
        if not isinstance(record, dict):
            raise ResultFileError(f"{path}: line {i} is not a JSON object")
        records.append(record)
    return records


def read_records(path, last_per_key: bool = True) -> list[dict]:
    """The records of the store ``path`` (read-only: an incomplete last line is ignored), the
    last one per key when a key appears more than once."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ResultFileError(f"{path}: no such results store") from None
    except OSError as exc:
        raise ResultFileError(f"{path}: cannot read the results store ({exc})") from None
    text = data.decode("utf-8", "replace")
    complete = text[: text.rfind("\n") + 1]
    records = _parse(complete.splitlines(), path)
    if not last_per_key:
        return records
    latest = {record_key(r): r for r in records}
    return list(latest.values())


class ResultStore:
    """A JSON Lines store opened for appending (a context manager): :attr:`records` holds what
    was there, :meth:`append` adds one record durably."""

    def __init__(self, path):
        self.path = Path(path)
        self.repaired = 0           # bytes of an incomplete last line dropped on opening
        self.records: list[dict] = []
        self._fd = None

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc):
        self.close()

    def open(self) -> "ResultStore":
        import fcntl

        if self.path.is_dir():
            raise ConfigError(f"{str(self.path)!r} is a folder; give a file name", key="--store")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_APPEND, 0o644)
        except OSError as exc:
            raise ConfigError(f"cannot open the results store {str(self.path)!r} ({exc.strerror})",
                              key="--store") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise ConfigError(f"the results store {str(self.path)!r} is in use by another run", key="--store") from None
        self._fd = fd
        try:
            self._load()
        except BaseException:
            self.close()
            raise
        return self

    def _load(self) -> None:
        size = os.fstat(self._fd).st_size
        data = os.pread(self._fd, size, 0) if size else b""
        end = data.rfind(b"\n") + 1
        if end < len(data):  # a write cut short: drop it, the solve is run again
            os.ftruncate(self._fd, end)
            os.fsync(self._fd)
            self.repaired = len(data) - end
        self.records = _parse(data[:end].decode("utf-8", "replace").splitlines(), self.path)

    def keys(self) -> set:
        return {record_key(r) for r in self.records}

    def append(self, record: dict) -> None:
        """Write ``record`` as one line (one write, then fsync)."""
        line = (json.dumps(record, sort_keys=True, allow_nan=False) + "\n").encode("utf-8")
        view = memoryview(line)
        while view:
            written = os.write(self._fd, view)
            view = view[written:]
        os.fsync(self._fd)
        self.records.append(record)

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # releases the lock
            self._fd = None
