"""benchmarks/_common.write_section: sections replaced atomically, hand-written notes kept."""

import sys

from fixtures import REPO

sys.path.insert(0, str(REPO / "benchmarks"))

from _common import write_section  # noqa: E402


def test_rewritten_section_keeps_its_hand_written_notes(tmp_path):
    path = tmp_path / "RESULTS.md"
    path.write_text("# r\n\n## A\n\nold table\n\n<!-- notes -->\nMeasured at abc.\n<!-- /notes -->\n\n"
                    "old failures\n\n## B\n\nb text\n", encoding="utf-8")
    write_section("A", "## A\n\nnew table\n", path=path)
    text = path.read_text(encoding="utf-8")
    assert text == ("# r\n\n## A\n\nnew table\n\n<!-- notes -->\nMeasured at abc.\n<!-- /notes -->\n\n"
                    "## B\n\nb text\n")
    write_section("B", "## B\n\nnew b\n", path=path)          # a section without notes
    assert text.replace("b text", "new b") == path.read_text(encoding="utf-8")
    write_section("C", "## C\n\nc\n", path=path)               # a new section is appended
    assert path.read_text(encoding="utf-8").endswith("## B\n\nnew b\n\n## C\n\nc\n")
