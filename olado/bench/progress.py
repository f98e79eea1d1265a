"""The progress display of ``olado bench``: running counts of solved and failed solves, as a
tqdm bar when tqdm is installed (the ``bench`` extra) and the stream is a terminal, else one
line rewritten in place on a terminal, or a line every ``every`` seconds in a log."""

from __future__ import annotations

import sys
import time


class Progress:
    """Counts of the records seen so far; :meth:`update` after each, :meth:`close` at the end."""

    def __init__(self, total: int, stream=None, every: float = 10.0, enabled: bool = True):
        self.total, self.stream, self.every, self.enabled = total, stream or sys.stderr, every, enabled
        self.solved = self.failed = 0
        self._t0 = self._last = time.monotonic()
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._bar = None
        if enabled and self._tty:
            try:
                from tqdm import tqdm

                self._bar = tqdm(total=total, file=self.stream, unit="solve", dynamic_ncols=True)
            except ImportError:
                pass

    @property
    def done(self) -> int:
        return self.solved + self.failed

    def _line(self) -> str:
        elapsed = time.monotonic() - self._t0
        return (f"{self.done}/{self.total} solves: {self.solved} solved, {self.failed} failed, "
                f"{elapsed:.0f} s")

    def update(self, record: dict) -> None:
        if record.get("success"):
            self.solved += 1
        else:
            self.failed += 1
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.set_postfix(solved=self.solved, failed=self.failed, refresh=False)
            self._bar.update(1)
            return
        now = time.monotonic()
        if self._tty:
            print("\r" + self._line(), end="", file=self.stream, flush=True)
        elif now - self._last >= self.every or self.done == self.total:
            print(self._line(), file=self.stream, flush=True)
            self._last = now

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        elif self.enabled and self._tty and self.done:
            print(file=self.stream, flush=True)
