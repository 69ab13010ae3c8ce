"""The documents a newcomer reads are current: the guide's key table is the schema's, the
README is a guide (not a diary) and names the two commands, and no code cites a file
outside the project."""

from __future__ import annotations

from pathlib import Path

from pipeline.config import KEYS, with_keys_table

ROOT = Path(__file__).resolve().parents[1]


def test_the_guide_holds_every_key_as_the_schema_says():
    text = (ROOT / "docs" / "guide.md").read_text()
    assert with_keys_table(text) == text, "run `make docs`"
    for dotted in KEYS:
        assert f"| `{dotted}` |" in text


def test_the_readme_is_a_guide_and_names_the_two_commands():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 260
    assert "make test" in text and "\nmake " in text
    for doc in ("docs/guide.md", "docs/method.md", "docs/performance.md", "docs/decisions.md"):
        assert doc in text and (ROOT / doc).exists(), doc


def test_no_code_cites_a_file_outside_the_project():
    for folder in ("pipeline", "stages", "tests"):
        for path in (ROOT / folder).rglob("*.py"):
            if path == Path(__file__).resolve():
                continue
            text = path.read_text()
            assert "METHOD.md" not in text and "DESIGN.md" not in text, path
