"""The plain progress display (no tqdm, or not a terminal): running counts of solved and failed."""

import io
import re

from olado.bench.progress import Progress


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_log_lines_and_final_line():
    out = io.StringIO()
    p = Progress(3, stream=out, every=3600.0)
    p.update({"success": True})
    p.update({"success": False})
    assert out.getvalue() == ""                          # not yet: a log gets a line every `every` s
    p.update({"success": True})
    p.close()
    assert out.getvalue().startswith("3/3 solves: 2 solved, 1 failed,")


def test_terminal_line_is_rewritten(monkeypatch):
    import builtins

    real_import = builtins.__import__

    def no_tqdm(name, *args, **kw):
        if name == "tqdm":
            raise ImportError(name)
        return real_import(name, *args, **kw)

    monkeypatch.setattr(builtins, "__import__", no_tqdm)
    out = _Tty()
    p = Progress(2, stream=out)
    p.update({"success": False})
    p.update({"success": True})
    p.close()
    text = out.getvalue()
    assert text.count("\r") == 2 and "\r1/2 solves: 0 solved, 1 failed" in text
    assert re.search(r"\r2/2 solves: 1 solved, 1 failed, \d+ s\n$", text)
